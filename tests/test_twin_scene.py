"""The twin's scene file: the default field, user edits, and clear errors."""

from __future__ import annotations

import subprocess
import sys

import pytest

from fpv_station.core.scene import DEFAULT_SCENE, SceneError, load_scene
from fpv_station.twin.sim import Sim


def test_default_scene_is_the_mission_field() -> None:
    scene = load_scene()
    assert (scene.field.size_x_m, scene.field.size_y_m) == (60.0, 37.0)
    assert scene.pad("start").x_m == -20.0 and scene.pad("landing").x_m == 20.0
    assert [(o.x_m, o.y_m, o.height_m) for o in scene.obstacles] == [(-7, 0, 3), (7, 0, 3)]
    assert [t.id for t in scene.tasks] == [1, 2, 3, 4]
    assert scene.home.lat_deg == pytest.approx(43.0021)


def test_an_edited_scene_moves_the_vehicle_and_obstacles(tmp_path) -> None:
    text = DEFAULT_SCENE.read_text().replace("x_m = -20.0", "x_m = -10.0", 1)
    path = tmp_path / "mine.toml"
    path.write_text(text)
    sim = Sim(load_scene(path))
    assert sim.pose().pos_enu_m[0] == -10.0


@pytest.mark.parametrize(
    "text, words",
    [
        ("[home]\nlat_deg = 123\n[[pads]]\nname='a'\nx_m=0\ny_m=0\n", "home.lat_deg"),
        (
            "[[pads]]\nname='a'\nx_m=0\ny_m=0\n[[tasks]]\nid=1\nname='t'\nstart_pad='a'\nend_pad='b'\n",
            "pad 'b'",
        ),
        ("name = \n", "not valid TOML"),
        ("name = 'no pads'\n", "at least one pad"),
        ("[[pads]]\nname='a'\nx_m=0\ny_m=0\ncolour='red'\n", "colour"),
    ],
)
def test_bad_scene_files_say_what_is_wrong(tmp_path, text: str, words: str) -> None:
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(SceneError, match=words.replace("(", r"\(")):
        load_scene(path)


def test_sim_cli_refuses_a_bad_scene_cleanly(tmp_path) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text("name = 'no pads'\n")
    out = subprocess.run(
        [sys.executable, "-m", "fpv_station.server", "sim", "--scene", str(bad)],
        capture_output=True,
        text=True,
        timeout=30,
    )
    assert out.returncode == 2
    assert "at least one pad" in out.stderr and "Traceback" not in out.stderr


def test_serve_refuses_a_bad_scene_in_settings_cleanly(tmp_path) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text("name = 'no pads'\n")
    config = tmp_path / "station.toml"
    config.write_text(f"[twin]\nscene = '{bad}'\n")
    out = subprocess.run(
        [
            sys.executable,
            "-m",
            "fpv_station.server",
            "serve",
            "--source",
            "sim",
            "--config",
            str(config),
            "--no-3d",
        ],
        capture_output=True,
        text=True,
        timeout=30,
    )
    assert out.returncode == 2
    assert "twin.scene" in out.stderr and "at least one pad" in out.stderr
