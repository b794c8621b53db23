"""Check `footage annotate --method motion` by eye: overlay the derived tracks on the clip (video + a few PNGs).

    PYTHONPATH=. python bench/bench_annotate_overlay.py [interchange] [--tracks viva_sitl/data/footage/interchange.tracks.csv]

Writes bench/out/<name>_tracks.mp4 and bench/out/<name>_frame<k>.png (git-ignored: footage-derived media is never
committed) and prints the track statistics recorded in bench/results_groundtruth.md.
"""

from __future__ import annotations

import argparse
import collections
import statistics
from pathlib import Path

import cv2
import numpy as np

from viva_sitl.cli_footage import default_tracks_path
from viva_sitl.footage import open_footage
from viva_sitl.footage.boxfiles import parse_viva
from viva_sitl.footage.loader import resolve_metadata

OUT = Path(__file__).resolve().parent / "out"


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("footage", nargs="?", default="interchange")
    ap.add_argument("--tracks", type=Path, help="tracks csv (default: beside the footage metadata)")
    ap.add_argument("--frames", default="0,60,120,170", help="frames to save as PNG")
    args = ap.parse_args()
    meta = resolve_metadata(args.footage)
    path = args.tracks or default_tracks_path(meta)
    rows = parse_viva(path)
    by_frame: dict[int, list] = collections.defaultdict(list)
    for r in rows:
        by_frame[r.frame].append(r)
    lengths = collections.Counter(r.track_id for r in rows)
    OUT.mkdir(exist_ok=True)
    save = {int(k) for k in args.frames.split(",")}
    with open_footage(args.footage) as src:
        h, w = src.geometry.height_px, src.geometry.width_px
        vid = cv2.VideoWriter(
            str(OUT / f"{meta.name}_tracks.mp4"), cv2.VideoWriter_fourcc(*"mp4v"), src.fps, (w, h)
        )
        rng = np.random.default_rng(0)
        colours = {tid: tuple(int(c) for c in rng.integers(64, 256, 3)) for tid in lengths}
        for i in range(src.frame_count):
            img = np.array(src.frame(i))
            for r in by_frame.get(i, []):
                c = colours[r.track_id]
                cv2.rectangle(
                    img,
                    (round(r.x0_px) - 2, round(r.y0_px) - 2),
                    (round(r.x1_px) + 2, round(r.y1_px) + 2),
                    c,
                    1,
                )
                cv2.putText(
                    img,
                    str(r.track_id),
                    (round(r.x1_px) + 3, round(r.y0_px)),
                    cv2.FONT_HERSHEY_SIMPLEX,
                    0.4,
                    c,
                    1,
                )
            vid.write(img)
            if i in save:
                cv2.imwrite(str(OUT / f"{meta.name}_frame{i}.png"), img)
        vid.release()
    per_frame = [len(by_frame.get(i, [])) for i in range(max(by_frame) + 1)]
    L = sorted(lengths.values())
    print(f"tracks file: {path}")
    print(
        f"tracks: {len(L)}; boxes: {len(rows)}; track length (frames) median {statistics.median(L)}, "
        f"p90 {L[int(0.9 * (len(L) - 1))]}, max {L[-1]}; >= 100 frames: {sum(v >= 100 for v in L)}"
    )
    print(
        f"boxes per frame: median {statistics.median(per_frame)}, min {min(per_frame)}, max {max(per_frame)}"
    )
    print(f"overlay: {OUT / (meta.name + '_tracks.mp4')}")


if __name__ == "__main__":
    main()
