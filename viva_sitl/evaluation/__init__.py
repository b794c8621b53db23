"""Landing trials: draw scenarios from a spec, fly a pilot through each, score the flights, compare pilots.

    spec.py      trial specs (TOML) and the scenarios drawn from (seed, trial index)
    runner.py    one in-process trial on the Vehicle loop; pilots.py: the in-process pilots (Python policies)
    external.py  one trial of an external program (MAVSDK / pymavlink) against `viva-sitl run --scenario`
    session.py   that scenario inside the app; human.py: `viva-sitl trials fly` (a person flies a trial)
    monitor.py   the trial's referee: scheduled events, the trajectory, the end of the trial
    scoring.py   per-trial scores (pure); stats.py: aggregates and paired statistics
    campaign.py  N trials in parallel, resumable; report.py: results.json/.csv, report.html, two-pilot compare
    cli.py       `viva-sitl trials run | fly | compare | show | scenarios`

Perception (super-resolution, datasets, detectors) is its own package, viva_sitl.perception.
"""
