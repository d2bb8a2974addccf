"""benchmarks/paired_rate.py: two trees side by side, cores swapped, each side importing
its own tree; bad trees are one line and exit 2."""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "benchmarks" / "paired_rate.py"


def _run(*args, cwd, tmpdir=None):
    env = dict(os.environ, TMPDIR=str(tmpdir)) if tmpdir else None
    return subprocess.run([sys.executable, str(SCRIPT), *args], capture_output=True, text=True,
                          timeout=600, cwd=cwd, env=env)  # fmt: skip


def test_a_tree_against_itself_pairs_swapped_cores_and_ends_at_the_same_point(tmp_path):
    out = tmp_path / "paired.json"
    r = _run("--a", str(ROOT), "--b", str(ROOT), "--scenario", "small", "--sim-s", "1",
             "--runs", "1", "--rounds", "1", "--warmup-s", "0", "--out", str(out),
             cwd=tmp_path)  # fmt: skip
    assert r.returncode == 0, r.stderr
    res = json.loads(out.read_text())
    assert len(res["pairs"]) == 2 and res["a_rev"] == res["b_rev"]
    if len(os.sched_getaffinity(0)) >= 2:  # each side on its own core, swapped next pair
        (p1, p2) = res["pairs"]
        assert p1["a_core"] != p1["b_core"]
        assert (p2["a_core"], p2["b_core"]) == (p1["b_core"], p1["a_core"])
    for q in res["pairs"]:
        assert q["ratio_cpu"] == pytest.approx(q["b"]["cpu_med_s"] / q["a"]["cpu_med_s"])
        assert q["a"]["cpu_med_s"] > 0 and q["b"]["cpu_med_s"] > 0
    assert res["same_end"] is True  # the same code, deterministic: the same end point
    assert res["a_rtf"] > 0 and "B / A thread CPU" in r.stdout


def test_each_side_imports_its_own_tree_and_nothing_else(tmp_path):
    # a "tree" whose lunar_drake lacks the modules: whatever fills them in (an editable
    # install of this checkout), its side fails, named, in one line, and the other side
    # is stopped
    fake = tmp_path / "fake"
    (fake / "lunar_drake").mkdir(parents=True)
    (fake / "lunar_drake" / "__init__.py").write_text("")
    r = _run("--a", str(ROOT), "--b", str(fake), "--scenario", "small", "--sim-s", "0.5",
             "--runs", "1", "--rounds", "1", "--warmup-s", "0", cwd=tmp_path,
             tmpdir=tmp_path)  # fmt: skip
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1
    assert "side B" in r.stderr and str(fake.resolve()) in r.stderr
    assert "lunar_drake" in r.stderr
    assert not list(tmp_path.glob("paired_rate_*.json"))  # nothing left behind


@pytest.mark.parametrize(
    ("args", "says"),
    [(["--a", "/nonexistent", "--b", "."], "--a = '/nonexistent' is not a lunar_drake source tree"),
     (["--a", ".", "--b", ".", "--runs", "0"], "--runs = 0; at least 1"),
     (["--a", "."], "--a and --b (two source trees) are required"),
     (["--a", ".", "--b", ".", "--out", "/nonexistent/dir/p.json"], "does not exist")],
)  # fmt: skip
def test_bad_input_is_one_line_and_exit_2(args, says):
    r = _run(*args, cwd=ROOT)
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert says in r.stderr
    if "--out" in args:  # ours, not argparse's (which adds a usage line)
        assert len(r.stderr.strip().splitlines()) == 1
