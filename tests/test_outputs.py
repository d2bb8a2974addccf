"""Outputs are written atomically, an unwritable destination fails early in one line, and
an interrupted command leaves nothing half-written (lunar_drake.files and its users).

Tests run as root, so "unwritable" is a destination whose parent is a regular file, or a
path under /proc, which root cannot write either.
"""

from __future__ import annotations

import hashlib
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import rasterio
from rasterio.transform import Affine

from lunar_drake import files
from lunar_drake.cli import main
from lunar_drake.errors import LunarDrakeError, OutputError
from lunar_drake.terrain.geotiff import GeoTiffWriter, write_geotiff
from lunar_drake.terrain.synth import OUTPUT_FILES, SynthConfig, synthesize_site

SPS = "+proj=stere +lat_0=-90 +lat_ts=-90 +lon_0=0 +R=1737400 +units=m +no_defs"
T = Affine(0.5, 0.0, 100.0, 0.0, -0.5, 200.0)
PROC_DIR = Path("/proc/lunar-drake-test-no-such-dir")


def _snapshot(d: Path) -> dict[str, str]:
    """Every entry under ``d`` (hidden ones too): relative path -> sha256 ("dir" for dirs)."""
    out = {}
    for p in sorted(d.rglob("*")):
        out[str(p.relative_to(d))] = (
            "dir" if p.is_dir() else hashlib.sha256(p.read_bytes()).hexdigest()
        )
    return out


def _afile(tmp_path: Path) -> Path:
    f = tmp_path / "afile"
    f.write_bytes(b"not a directory\n")
    return f


def _one_line_error(err: str, path) -> None:
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert "Traceback" not in err
    assert lines[0].startswith("lunar-drake: error: OutputError: ")
    assert str(path) in lines[0]


def _small_config(**kw) -> SynthConfig:
    base = dict(
        size_px=64, resolution_m=0.1, factor=8, seed=3, min_crater_m=0.5, tile_px=32, workers=2
    )
    base.update(kw)
    return SynthConfig(**base)


# ------------------------------------------------------------------ the atomic helpers


def test_atomic_write_keeps_the_old_file_on_failure(tmp_path, monkeypatch):
    p = tmp_path / "a.json"
    files.atomic_write_text(p, '{"v": 1}\n')
    assert p.read_bytes() == b'{"v": 1}\n'
    files.atomic_write_bytes(p, b'{"v": 2}\n')
    assert p.read_bytes() == b'{"v": 2}\n'

    # The write itself fails half-way.
    with pytest.raises(RuntimeError, match="half-way"):
        with files.atomic_path(p) as tmp:
            tmp.write_text('{"v": 3, "trunc')
            raise RuntimeError("half-way")
    assert os.listdir(tmp_path) == ["a.json"] and p.read_bytes() == b'{"v": 2}\n'

    # Ctrl-C while writing.
    with pytest.raises(KeyboardInterrupt):
        with files.atomic_path(p) as tmp:
            tmp.write_text("partial")
            raise KeyboardInterrupt
    assert os.listdir(tmp_path) == ["a.json"] and p.read_bytes() == b'{"v": 2}\n'

    # The rename fails (e.g. disk full): an OutputError naming the path and the reason.
    def boom(src, dst):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "replace", boom)
    with pytest.raises(OutputError, match=r"a\.json.*No space left on device"):
        files.atomic_write_text(p, "new")
    monkeypatch.undo()
    assert os.listdir(tmp_path) == ["a.json"] and p.read_bytes() == b'{"v": 2}\n'

    # No directory to write in.
    with pytest.raises(OutputError, match="does not exist"):
        files.atomic_write_text(tmp_path / "missing" / "b.json", "x")
    assert os.listdir(tmp_path) == ["a.json"]


def test_temp_sibling_is_hidden_unique_and_keeps_the_suffix(tmp_path):
    a = files.temp_sibling(tmp_path / "dem.tif")
    b = files.temp_sibling(tmp_path / "dem.tif")
    assert a != b and a.parent == tmp_path
    assert a.name.startswith(".dem.tmp-") and a.suffix == ".tif"


def test_check_output_file(tmp_path):
    afile = _afile(tmp_path)
    assert files.check_output_file(tmp_path / "ok.tif") == tmp_path / "ok.tif"
    with pytest.raises(OutputError, match="is a directory"):
        files.check_output_file(tmp_path)
    with pytest.raises(OutputError, match="is not a directory"):
        files.check_output_file(afile / "x.tif")
    with pytest.raises(OutputError, match="does not exist"):
        files.check_output_file(tmp_path / "missing" / "x.tif")
    with pytest.raises(OutputError, match=r"/proc/x\.tif"):
        files.check_output_file("/proc/x.tif")
    assert os.listdir(tmp_path) == ["afile"]  # the probe is gone


def test_ensure_output_dir(tmp_path):
    afile = _afile(tmp_path)
    assert files.ensure_output_dir(tmp_path / "a" / "b").is_dir()
    with pytest.raises(OutputError, match="exists and is not a directory"):
        files.ensure_output_dir(afile)
    with pytest.raises(OutputError, match="Not a directory"):
        files.ensure_output_dir(afile / "sub")
    with pytest.raises(OutputError, match=str(PROC_DIR)):
        files.ensure_output_dir(PROC_DIR)


def test_staged_directory_interrupted_leaves_the_old_directory_byte_identical(tmp_path):
    d = tmp_path / "out"
    (d / "sub").mkdir(parents=True)
    (d / "keep.txt").write_text("old\n")
    (d / "sub" / "data.bin").write_bytes(bytes(range(256)))
    before = _snapshot(tmp_path)

    for exc in (KeyboardInterrupt, RuntimeError):
        with pytest.raises(exc):
            with files.staged_directory(d) as stage:
                assert stage.parent == tmp_path and stage.name.startswith(".out.tmp-")
                (stage / "keep.txt").write_text("new\n")
                (stage / "other.txt").write_text("half")
                raise exc()
        assert _snapshot(tmp_path) == before

    # Success replaces the directory as a whole and leaves no sibling behind.
    with files.staged_directory(d) as stage:
        (stage / "new.txt").write_text("new\n")
    assert os.listdir(tmp_path) == ["out"] and os.listdir(d) == ["new.txt"]


def test_staged_directory_interrupted_removes_the_parents_it_created(tmp_path):
    target = tmp_path / "a" / "b" / "out"
    with pytest.raises(KeyboardInterrupt):
        with files.staged_directory(target) as stage:
            assert stage.parent == tmp_path / "a" / "b"
            (stage / "x").write_text("x")
            raise KeyboardInterrupt
    assert os.listdir(tmp_path) == []
    # A parent that existed before stays.
    (tmp_path / "a").mkdir()
    with pytest.raises(KeyboardInterrupt):
        with files.staged_directory(target):
            raise KeyboardInterrupt
    assert os.listdir(tmp_path) == ["a"] and os.listdir(tmp_path / "a") == []


def test_staged_directory_refuses_unwritable_paths_before_the_work(tmp_path):
    afile = _afile(tmp_path)
    for path, reason in (
        (afile, "exists and is not a directory"),
        (afile / "out", "Not a directory"),
        (afile / "sub" / "out", "Not a directory"),
        (PROC_DIR / "out", str(PROC_DIR)),
    ):
        ran = []
        with pytest.raises(OutputError, match=reason):
            with files.staged_directory(path):
                ran.append(True)
        assert not ran
    assert os.listdir(tmp_path) == ["afile"] and afile.read_bytes() == b"not a directory\n"


# ------------------------------------------------------- GeoTIFF writers: cleanup never masks


def test_geotiff_writers_report_unwritable_destinations(tmp_path):
    z = np.ones((40, 40), np.float32)
    with pytest.raises(OutputError, match=r"cannot write raster '/proc/lunar-drake-x\.tif'"):
        write_geotiff("/proc/lunar-drake-x.tif", z, transform=T, crs=SPS)
    with pytest.raises(OutputError, match=r"/proc/lunar-drake-x\.tif"):
        with GeoTiffWriter("/proc/lunar-drake-x.tif", height=40, width=40, transform=T, crs=SPS):
            pass
    afile = _afile(tmp_path)
    with pytest.raises(LunarDrakeError, match="is not a directory"):
        write_geotiff(afile / "x.tif", z, transform=T, crs=SPS)
    assert os.listdir(tmp_path) == ["afile"]


def test_geotiff_writer_error_is_not_masked_by_a_failing_close(tmp_path, monkeypatch):
    def bad_close(self):
        raise OSError("close failed (simulated)")

    with pytest.raises(RuntimeError, match="the real error"):
        with GeoTiffWriter(tmp_path / "a.tif", height=40, width=40, transform=T, crs=SPS) as w:
            w.write(np.ones((40, 40), np.float32), row0=0, col0=0)
            monkeypatch.setattr(rasterio.io.DatasetWriter, "close", bad_close)
            raise RuntimeError("the real error")
    monkeypatch.undo()
    assert os.listdir(tmp_path) == []


# --------------------------------------------------------------------- lunar-drake CLIs


@pytest.mark.parametrize("where", ["file-parent", "file-grandparent", "proc"])
def test_terrain_synth_unwritable_out_is_one_line(tmp_path, capsys, where):
    afile = _afile(tmp_path)
    out = {
        "file-parent": afile / "site",
        "file-grandparent": afile / "sub" / "site",
        "proc": PROC_DIR / "site",
    }[where]
    argv = ["terrain", "synth", "--size", "64", "--factor", "8", "--out", str(out)]
    assert main([*argv, "--no-progress"]) == 2
    _one_line_error(capsys.readouterr().err, out)
    assert os.listdir(tmp_path) == ["afile"] and afile.read_bytes() == b"not a directory\n"


def test_terrain_synth_refuses_to_replace_a_folder_of_other_files(tmp_path, capsys):
    (tmp_path / "notes.txt").write_text("mine\n")
    before = _snapshot(tmp_path)
    argv = ["terrain", "synth", "--size", "64", "--factor", "8", "--out", str(tmp_path)]
    assert main([*argv, "--no-progress"]) == 2
    err = capsys.readouterr().err
    _one_line_error(err, tmp_path)
    assert "not a site output" in err and "notes.txt" in err
    assert _snapshot(tmp_path) == before


@pytest.fixture
def dem_file(tmp_path):
    z = np.random.default_rng(0).normal(scale=0.3, size=(32, 32)).astype(np.float32)
    path = tmp_path / "dem.tif"
    write_geotiff(path, z, transform=T, crs=SPS)
    return path


@pytest.mark.parametrize("where", ["file-parent", "proc", "directory"])
def test_lightmap_unwritable_out_is_one_line_before_the_bake(
    dem_file, tmp_path, capsys, monkeypatch, where
):
    from lunar_drake.render import lightmap as lm

    def no_bake(*args, **kwargs):
        raise AssertionError("the bake started before the output was checked")

    monkeypatch.setattr(lm, "lightmap_dask", no_bake)
    afile = _afile(tmp_path)
    out = {
        "file-parent": afile / "lm.tif",
        "proc": Path("/proc/lunar-drake-lm.tif"),
        "directory": tmp_path,
    }[where]
    before = _snapshot(tmp_path)
    argv = ["lightmap", str(dem_file), "--out", str(out), "--sun-az", "270", "--sun-el", "8"]
    assert main([*argv, "--no-progress"]) == 2
    _one_line_error(capsys.readouterr().err, out)
    assert _snapshot(tmp_path) == before


@pytest.mark.parametrize("where", ["cache-is-a-file", "cache-under-a-file", "proc"])
def test_ephemeris_unwritable_kernel_cache_is_one_line(tmp_path, capsys, monkeypatch, where):
    from lunar_drake.ephemeris import kernels

    afile = _afile(tmp_path)
    cache = {
        "cache-is-a-file": afile,
        "cache-under-a-file": afile / "cache",
        "proc": PROC_DIR,
    }[where]
    monkeypatch.setenv("LUNAR_DRAKE_CACHE", str(cache))
    try:
        argv = ["ephemeris", "--utc", "2027-11-20T12:00:00", "--lat", "-89.5", "--lon", "0"]
        assert main(argv) == 2
    finally:
        kernels.unload_kernels()  # the next user re-verifies its own cache
    err = capsys.readouterr().err
    _one_line_error(err, cache / "spice")
    assert "LUNAR_DRAKE_CACHE" in err
    assert os.listdir(tmp_path) == ["afile"] and afile.read_bytes() == b"not a directory\n"


def test_interrupted_kernel_build_leaves_no_temporary_files(tmp_path, monkeypatch):
    from lunar_drake.ephemeris import kernels

    def interrupted(path, records):
        Path(path).write_bytes(b"partial SPK")
        raise KeyboardInterrupt

    monkeypatch.setattr(kernels, "_write_spk", interrupted)
    with pytest.raises(KeyboardInterrupt):
        kernels.build_kernels(tmp_path / "spice")
    assert os.listdir(tmp_path / "spice") == []


# ------------------------------------------------------------ interrupted site synthesis


def test_overview_leaves_the_matplotlib_backend_alone(tmp_path, monkeypatch):
    """Library code never calls matplotlib.use nor imports pyplot (a notebook keeps its
    inline backend)."""
    import matplotlib

    def no_use(*args, **kwargs):
        raise AssertionError("library code called matplotlib.use")

    monkeypatch.setattr(matplotlib, "use", no_use)
    monkeypatch.setitem(sys.modules, "matplotlib.pyplot", None)  # importing it now fails
    synthesize_site(config=_small_config(), out_dir=tmp_path / "site", progress=False)
    png = (tmp_path / "site" / "overview.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n"
    assert int.from_bytes(png[16:20], "big") == 1650  # 15 in at 110 dpi


def test_interrupted_synthesis_leaves_nothing(tmp_path, monkeypatch):
    from lunar_drake.terrain import overview

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt  # Ctrl-C while the last file, overview.png, is drawn

    monkeypatch.setattr(overview, "write_overview", interrupted)
    out = tmp_path / "new" / "site"
    with pytest.raises(KeyboardInterrupt):
        synthesize_site(config=_small_config(), out_dir=out, progress=False)
    assert os.listdir(tmp_path) == []  # no site, no staging sibling, no created parent


def test_interrupted_synthesis_keeps_an_existing_site_untouched(tmp_path, monkeypatch):
    from lunar_drake.terrain import overview, surface

    out = tmp_path / "site"
    products = synthesize_site(config=_small_config(), out_dir=out, progress=False)
    assert products.out_dir == out and sorted(os.listdir(out)) == sorted(OUTPUT_FILES)
    before = _snapshot(tmp_path)

    # Ctrl-C at the last step, then while tiles are written (the GeoTIFF writers open).
    monkeypatch.setattr(overview, "write_overview", lambda *a, **k: _raise(KeyboardInterrupt))
    with pytest.raises(KeyboardInterrupt):
        synthesize_site(config=_small_config(seed=4), out_dir=out, progress=False)
    assert _snapshot(tmp_path) == before
    monkeypatch.undo()
    monkeypatch.setattr(surface, "normals_from_dem", lambda *a, **k: _raise(KeyboardInterrupt))
    with pytest.raises(KeyboardInterrupt):
        synthesize_site(config=_small_config(seed=4), out_dir=out, progress=False)
    assert _snapshot(tmp_path) == before
    # An ordinary error in a tile is raised as itself (cleanup does not mask it).
    monkeypatch.setattr(surface, "normals_from_dem", lambda *a, **k: _raise(ValueError("tile")))
    with pytest.raises(ValueError, match="tile"):
        synthesize_site(config=_small_config(seed=4), out_dir=out, progress=False)
    assert _snapshot(tmp_path) == before
    monkeypatch.undo()

    # A successful synthesis replaces the site as a whole.
    synthesize_site(config=_small_config(seed=4), out_dir=out, progress=False, overview=False)
    assert os.listdir(tmp_path) == ["site"]
    assert sorted(os.listdir(out)) == sorted(f for f in OUTPUT_FILES if f != "overview.png")
    assert _snapshot(tmp_path)["site/dem.tif"] != before["site/dem.tif"]


def _raise(exc):
    raise exc


def test_site_cache_entry_appears_only_when_complete(tmp_path, monkeypatch):
    """lunar_drake.site.ensure_site (which stages its own cache entry too) still builds
    once, reuses the entry, and leaves no entry after an interrupted build."""
    from lunar_drake.scenario import Scenario, TerrainConfig
    from lunar_drake.site import ensure_site
    from lunar_drake.terrain import overview

    terrain = TerrainConfig(size_px=64, resolution_m=0.1, factor=8, tile_px=32)
    scenario = Scenario(random_seed=7, terrain=terrain)
    monkeypatch.setattr(overview, "write_overview", lambda *a, **k: _raise(KeyboardInterrupt))
    with pytest.raises(KeyboardInterrupt):
        ensure_site(scenario, cache_dir=tmp_path, progress=False)
    assert os.listdir(tmp_path / "sites") == []
    monkeypatch.undo()
    first = ensure_site(scenario, cache_dir=tmp_path, progress=False)
    again = ensure_site(scenario, cache_dir=tmp_path, progress=False)
    assert not first.cached and again.cached and again.directory == first.directory
    assert os.listdir(tmp_path / "sites") == [first.directory.name]
    assert sorted(os.listdir(first.directory)) == sorted(OUTPUT_FILES)


def test_sigint_leaves_the_complete_site_or_nothing(tmp_path):
    out = tmp_path / "site"
    cmd = [sys.executable, "-m", "lunar_drake.cli", "terrain", "synth", "--size", "1024"]
    cmd += ["--factor", "32", "--tile", "256", "--out", str(out), "--no-progress"]
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env)
    try:
        # Interrupt once the synthesis runs (its staging directory exists), not at import.
        deadline = time.monotonic() + 60.0
        while not any(p.name.startswith(".site.tmp-") for p in tmp_path.iterdir()):
            if proc.poll() is not None or time.monotonic() > deadline:
                break
            time.sleep(0.05)
        time.sleep(0.5)
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    err = err.decode(errors="replace")
    names = os.listdir(tmp_path)
    assert names in ([], ["site"]), names  # no temporary sibling either way
    if names:
        assert sorted(os.listdir(out)) == sorted(OUTPUT_FILES)
    else:
        assert proc.returncode != 0, err
    assert "Traceback" not in err, err  # cli.main reports Ctrl-C in one line


def test_stale_staging_directories_go_when_the_next_build_starts(tmp_path):
    """A build killed outright (SIGKILL) leaves its staging directory; the next build
    into the same place removes it, but never one of a process that still runs, of
    another machine (a shared disk), of another name (``world.1``), nor a set-aside
    previous output (``.old-``) while the destination is missing: it may be the only
    copy."""
    from lunar_drake.files import _HOST, remove_stale_siblings, staged_directory

    gone = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True, check=True)  # fmt: skip
    dead = int(gone.stdout)
    out = tmp_path / "world"

    def stage(name, tag, pid, host=_HOST):
        d = tmp_path / f".{name}.{tag}-{pid}-{host}deadbeef"
        d.mkdir()
        (d / "part.tif").write_bytes(b"x")
        return d

    tmp_dead, old_dead = stage("world", "tmp", dead), stage("world", "old", dead)
    kept = [stage("world", "tmp", os.getpid()), stage("world", "tmp", dead, "0123abcd"),
            stage("worlds", "tmp", dead)]  # fmt: skip
    suffixed = tmp_path / f".world.old-{dead}-{_HOST}deadbeef.1"  # world.1's only copy
    suffixed.mkdir()
    # No destination yet: the dead build's staging goes, its set-aside output stays.
    assert remove_stale_siblings(out) == [tmp_dead]
    with staged_directory(out) as tmp:
        (tmp / "a.txt").write_text("one")
    assert old_dead.is_dir()  # still there: the destination did not exist at the start
    with staged_directory(out) as tmp:
        (tmp / "a.txt").write_text("two")
    assert (out / "a.txt").read_text() == "two"
    assert not old_dead.exists()
    assert all(k.is_dir() for k in kept) and suffixed.is_dir()
