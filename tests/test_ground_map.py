"""``ground_map.png``: hazards told apart by origin (the a-priori map's, stereo's,
unconfirmed), and a map written by every run that plans, cameras or not."""

import json

import numpy as np

from lunar_drake.autonomy.costmap import Costmap
from lunar_drake.cli import main
from lunar_drake.ground_map import hazard_classes


def _costmap(lethal, unconfirmed=None):
    lethal = np.asarray(lethal, bool)
    z = np.zeros(lethal.shape)
    return Costmap(cost=np.where(lethal, np.inf, 1.0), slope_deg=z, step_m=z, roughness_m=z,
                   lethal_raw=lethal, x0_m=0.0, y1_m=float(lethal.shape[0]), resolution_m=1.0,
                   unconfirmed=unconfirmed)  # fmt: skip


def test_hazards_are_classed_by_where_they_came_from():
    prior = np.zeros((4, 5), bool)
    prior[0, 0] = prior[1, 1] = True  # the a-priori map's hazards
    steep = np.zeros((4, 5), bool)
    steep[3, 4] = True  # steep on the orbital map, unseen: lethal in both
    final = prior.copy()
    final[2, 3] = True  # found by stereo
    final[1, 1] = True
    classes = hazard_classes(_costmap(final | steep, steep), _costmap(prior | steep, steep))
    assert np.argwhere(classes["stereo"]).tolist() == [[2, 3]]
    assert np.argwhere(classes["map"]).tolist() == [[0, 0], [1, 1]]
    assert np.argwhere(classes["unconfirmed"]).tolist() == [[3, 4]]
    # No prior (or one on another grid): every lethal cell is the map's.
    alone = hazard_classes(_costmap(final))
    assert not alone["stereo"].any() and alone["map"].sum() == 3
    other = hazard_classes(_costmap(final), _costmap(np.zeros((2, 2), bool)))
    assert not other["stereo"].any()


def test_a_run_without_cameras_writes_the_a_priori_map(cache, tmp_path, capsys):
    out = tmp_path / "run"
    args = ["run", "--scenario", "goto", "--no-cameras", "--duration", "4", "--no-meshcat",
            "--no-progress", "--out", str(out)]  # fmt: skip
    assert main(args) == 0
    printed = capsys.readouterr().out
    png = (out / "ground_map.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 20_000
    assert "ground_map.png" in printed.splitlines()[-1]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["camera_frames"] == 0 and summary["perception"]["keyframes"] == 0
    # Deterministic: the same run, the same picture.
    again = tmp_path / "again"
    assert main([*args[:-1], str(again)]) == 0
    assert (again / "ground_map.png").read_bytes() == png
