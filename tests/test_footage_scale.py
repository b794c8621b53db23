"""Any picture a user brings renders: its recording scale from DJI XMP / EXIF, flags or the paper's defaults (one
warning), never a refusal; and where it lies on Earth (config home, PX4_HOME_*, its own GPS)."""

from __future__ import annotations

import math
import os
import struct
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
from PIL import Image

from viva_sitl.app import config_from_args
from viva_sitl.cli import build_parser
from viva_sitl.config import ConfigError, SimConfig
from viva_sitl.footage import open_footage
from viva_sitl.footage.exif import hfov_from_diagonal, read_photo_scale
from viva_sitl.geo import GeoOrigin, home_from_env, parse_home
from viva_sitl.sim import Simulator

REPO = Path(__file__).resolve().parents[1]
W, H = 800, 600  # a 4:3 photo, as DJI stills


def xmp_packet(**dji: str) -> bytes:
    attrs = "\n".join(f'   drone-dji:{k}="{v}"' for k, v in dji.items())
    return (
        '<?xpacket begin="\ufeff" id="W5M0MpCehiHzreSzNTczkc9d"?>\n<x:xmpmeta xmlns:x="adobe:ns:meta/">\n'
        ' <rdf:RDF xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#">\n'
        '  <rdf:Description rdf:about="DJI Meta Data" xmlns:drone-dji="http://www.dji.com/drone-dji/1.0/"\n'
        f'{attrs}>\n  </rdf:Description>\n </rdf:RDF>\n</x:xmpmeta>\n<?xpacket end="w"?>'
    ).encode()


def write_photo(
    path: Path, *, model: str | None = None, f35_mm: int | None = None, xmp: bytes | None = None
) -> Path:
    """A textured JPEG with the given EXIF (Pillow) and an XMP APP1 segment written by hand after SOI."""
    rng = np.random.default_rng(1)
    img = cv2.GaussianBlur(rng.integers(0, 255, (H, W, 3), dtype=np.uint8), (0, 0), 3)
    exif = Image.Exif()
    if model is not None:
        exif[0x010F] = "DJI"
        exif[0x0110] = model
    if f35_mm is not None:
        exif.get_ifd(0x8769)[0xA405] = f35_mm
    Image.fromarray(img[:, :, ::-1]).save(path, "JPEG", quality=90, exif=exif.tobytes())
    if xmp is not None:
        data = path.read_bytes()
        assert data[:2] == b"\xff\xd8"
        payload = b"http://ns.adobe.com/xap/1.0/\x00" + xmp
        seg = b"\xff\xe1" + struct.pack(">H", len(payload) + 2) + payload
        path.write_bytes(data[:2] + seg + data[2:])
    return path


def test_dji_xmp_altitude_and_camera_model_give_the_scale(tmp_path: Path) -> None:
    photo = write_photo(
        tmp_path / "DJI_0001.JPG",
        model="FC8482",
        xmp=xmp_packet(
            RelativeAltitude="+87.30", GpsLatitude="19.432608", GpsLongitude="-99.133209",
            GimbalYawDegree="-30.5", GimbalPitchDegree="-90.0",
        ),
    )  # fmt: skip
    scale = read_photo_scale(photo)
    assert scale.relative_altitude_m == 87.3
    with open_footage(photo) as src:
        g = src.geometry
        assert g.recording_altitude_m == pytest.approx(87.3)
        # Mini 4 Pro: 82.1 deg diagonal, on a 4:3 picture
        assert g.recording_hfov_deg == pytest.approx(hfov_from_diagonal(82.1, W, H), abs=1e-6)
        assert g.recording_hfov_deg == pytest.approx(
            2 * math.degrees(math.atan(math.tan(math.radians(41.05)) * 0.8))
        )
        assert g.heading_deg == pytest.approx(329.5)  # gimbal yaw -30.5 deg: image top points NNW
        assert g.geo_origin is not None
        assert (g.geo_origin.lat_deg, g.geo_origin.lon_deg) == pytest.approx((19.432608, -99.133209))
    # explicit flags beat the photo
    with open_footage(photo, altitude_m=50.0, hfov_deg=60.0) as src:
        assert src.geometry.recording_altitude_m == 50.0
        assert src.geometry.recording_hfov_deg == pytest.approx(60.0)


def test_exif_35mm_focal_length_gives_the_fov(tmp_path: Path) -> None:
    photo = write_photo(
        tmp_path / "IMG.jpg", model="SomeCam 3000", f35_mm=24, xmp=xmp_packet(RelativeAltitude="120")
    )
    with open_footage(photo) as src:
        dfov = 2 * math.degrees(math.atan(21.633 / 24.0))  # 84.1 deg diagonal for 24 mm equivalent
        assert src.geometry.recording_hfov_deg == pytest.approx(hfov_from_diagonal(dfov, W, H), abs=1e-3)
        assert src.geometry.recording_altitude_m == 120.0
        # ground width = 2 z tan(hfov / 2)
        assert src.geometry.ground_width_m == pytest.approx(
            2 * 120.0 * math.tan(math.radians(src.geometry.recording_hfov_deg) / 2), rel=1e-9
        )


def test_an_unknown_photo_renders_with_the_papers_defaults_and_one_warning(tmp_path: Path) -> None:
    photo = write_photo(tmp_path / "holiday.jpg")
    out = tmp_path / "view.png"
    env = dict(os.environ, PYTHONPATH=str(REPO))
    res = subprocess.run(
        [sys.executable, "-m", "viva_sitl", "render", "--footage", str(photo), "--pose", "0,0,50,0,0,0", "-o", str(out)],
        capture_output=True, text=True, timeout=120, env=env, cwd=tmp_path,
    )  # fmt: skip
    assert res.returncode == 0, res.stderr
    warnings = [ln for ln in res.stderr.splitlines() if "WARNING" in ln]
    assert len(warnings) == 1, res.stderr
    assert "82.1" in warnings[0] and "100" in warnings[0] and "--footage-alt" in warnings[0]
    view = cv2.imread(str(out))
    assert view is not None and view.shape == (480, 640, 3)
    assert "coverage 1.00" in res.stdout  # 50 m up over a picture taken from 100 m: all footage
    with open_footage(photo) as src:
        assert src.geometry.recording_altitude_m == 100.0
        assert src.geometry.recording_hfov_deg == pytest.approx(82.1)


def test_gsd_alone_needs_no_altitude(tmp_path: Path) -> None:
    photo = write_photo(tmp_path / "ortho.png")
    with open_footage(photo, gsd_m_per_px=0.05) as src:  # altitude from the default FoV
        assert src.geometry.gsd_m_per_px == 0.05
        assert src.geometry.recording_hfov_deg == pytest.approx(82.1)


def test_config_scale_keys_reach_the_footage(tmp_path: Path) -> None:
    photo = write_photo(tmp_path / "p.jpg")
    cfg = SimConfig.from_dict(
        {"sim": {"footage": str(photo), "footage_alt_m": 40.0, "footage_hfov_deg": 70.0}}
    )
    with Simulator(cfg) as sim:
        assert sim.footage.geometry.recording_altitude_m == 40.0
        assert sim.footage.geometry.recording_hfov_deg == pytest.approx(70.0)
    with pytest.raises(ConfigError, match="footage_hfov_deg must be < 180"):
        SimConfig.from_dict({"sim": {"footage_hfov_deg": 190.0}})


# --- placement ---------------------------------------------------------------------------------------------------------
def test_home_forms_in_config() -> None:
    expect = GeoOrigin(47.397742, 8.545594, 488.0)
    assert SimConfig.from_dict({"sim": {"home": "47.397742,8.545594,488"}}).home == expect
    assert SimConfig.from_dict({"sim": {"home": "47.397742, 8.545594"}}).home == expect  # ALT: PX4's 488 m
    assert SimConfig.from_dict({"sim": {"home": [47.397742, 8.545594, 488.0]}}).home == expect
    table = {"lat_deg": 47.397742, "lon_deg": 8.545594, "alt_amsl_m": 488.0}
    assert SimConfig.from_dict({"sim": {"home": table}}).home == expect
    with pytest.raises(ConfigError, match=r"\[sim\]\.home: home longitude must be in \[-180, 180\]"):
        SimConfig.from_dict({"sim": {"home": "47,190"}})
    with pytest.raises(ConfigError, match="latitude"):
        SimConfig.from_dict({"sim": {"home": {"lat_deg": 91.0, "lon_deg": 0.0}}})


def test_home_precedence_cli_config_env(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    parser = build_parser()
    monkeypatch.setenv("PX4_HOME_LAT", "-33.8568")
    monkeypatch.setenv("PX4_HOME_LON", "151.2153")
    monkeypatch.delenv("PX4_HOME_ALT", raising=False)
    assert config_from_args(parser.parse_args(["run"])).home == GeoOrigin(-33.8568, 151.2153, 488.0)
    cfg = tmp_path / "c.toml"
    cfg.write_text('[sim]\nhome = "10,20,30"\n')
    assert config_from_args(parser.parse_args(["run", "--config", str(cfg)])).home == GeoOrigin(10, 20, 30)
    args = parser.parse_args(["run", "--config", str(cfg), "--home", "47.397742,8.545594,488"])
    assert config_from_args(args).home == GeoOrigin(47.397742, 8.545594, 488.0)
    monkeypatch.delenv("PX4_HOME_LAT")
    monkeypatch.delenv("PX4_HOME_LON")
    assert config_from_args(parser.parse_args(["run"])).home is None  # the footage's own place, else PX4's


def test_home_parsing() -> None:
    assert parse_home("1.5,2.5,3") == GeoOrigin(1.5, 2.5, 3.0)
    assert home_from_env({}) is None
    assert home_from_env({"PX4_HOME_LAT": "1", "PX4_HOME_LON": "2", "PX4_HOME_ALT": "3"}) == GeoOrigin(
        1, 2, 3
    )
    for bad in ("", "1", "1,2,3,4", "a,b", "nan,0", "0,inf"):
        with pytest.raises(ValueError):
            parse_home(bad)
    with pytest.raises(ValueError, match="PX4_HOME_ALT is set"):
        home_from_env({"PX4_HOME_ALT": "5"})


def test_geo_referenced_footage_keeps_its_place_unless_told(tmp_path: Path) -> None:
    photo = write_photo(
        tmp_path / "g.jpg", xmp=xmp_packet(RelativeAltitude="60", GpsLatitude="19.4", GpsLongitude="-99.1")
    )
    with Simulator(SimConfig(footage=str(photo))) as sim:
        assert (sim.geo.lat_deg, sim.geo.lon_deg) == pytest.approx((19.4, -99.1))
    with Simulator(SimConfig(footage=str(photo), home=GeoOrigin(47.397742, 8.545594, 488.0))) as sim:
        assert (sim.geo.lat_deg, sim.geo.lon_deg, sim.geo.alt_amsl_m) == (47.397742, 8.545594, 488.0)
        meta = sim.render().meta  # the frame-and-pose ground truth follows the placement
        assert (meta.lat_deg, meta.lon_deg) == pytest.approx((47.397742, 8.545594))


def test_render_flags_set_the_scale_without_a_warning(tmp_path: Path) -> None:
    photo = write_photo(tmp_path / "holiday.jpg")
    out = tmp_path / "view.png"
    env = dict(os.environ, PYTHONPATH=str(REPO))
    args = ["render", "--footage", str(photo), "--pose", "0,0,25,0,0,0", "-o", str(out)]
    res = subprocess.run(
        [sys.executable, "-m", "viva_sitl", *args, "--footage-alt", "50", "--footage-hfov", "60"],
        capture_output=True, text=True, timeout=120, env=env, cwd=tmp_path,
    )  # fmt: skip
    assert res.returncode == 0, res.stderr
    assert "WARNING" not in res.stderr
    # 25 m up over a 57.7 m x 43.3 m picture (60 deg from 50 m): the VAC's 43.5 m x 32.6 m view is all footage
    assert "coverage 1.00" in res.stdout and cv2.imread(str(out)) is not None
