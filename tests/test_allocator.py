"""The programs' malloc setting (lunar_drake/allocator.py): glibc's tcache raised once,
by re-executing the command, unless the user set it or opted out."""

from __future__ import annotations

import os
import platform
import subprocess
import sys

import pytest

from lunar_drake.allocator import (
    TCACHE_COUNT,
    reexec_with_malloc_tunables,
    tunables_to_set,
    with_tcache,
)
from lunar_drake.errors import ConfigError

ON_GLIBC = sys.platform == "linux" and platform.libc_ver()[0] == "glibc"


def test_the_tunable_is_added_to_the_others_and_never_overrides_one_set():
    tc = f"glibc.malloc.tcache_count={TCACHE_COUNT}"
    assert with_tcache(None) == tc and with_tcache("") == tc
    assert (
        with_tcache("glibc.malloc.trim_threshold=4096") == f"glibc.malloc.trim_threshold=4096:{tc}"
    )
    assert with_tcache("glibc.malloc.tcache_count=7") is None
    assert with_tcache("glibc.malloc.mxfast=0:glibc.malloc.tcache_count=20") is None
    assert tunables_to_set({"LUNAR_DRAKE_MALLOC": "default"}) is None
    assert tunables_to_set({"GLIBC_TUNABLES": "glibc.malloc.tcache_count=7"}) is None


@pytest.mark.skipif(not ON_GLIBC, reason="glibc's tunables only")
def test_reexec_runs_the_same_command_with_the_tunable_once():
    calls = []
    env = {"PATH": "/bin", "GLIBC_TUNABLES": "glibc.malloc.mxfast=0"}
    assert reexec_with_malloc_tunables(environ=env, execv=lambda *a: calls.append(a))
    ((exe, argv, new_env),) = calls
    assert exe == sys.executable and argv == [sys.executable, *sys.orig_argv[1:]]
    assert (
        new_env["GLIBC_TUNABLES"]
        == f"glibc.malloc.mxfast=0:glibc.malloc.tcache_count={TCACHE_COUNT}"
    )
    assert new_env["PATH"] == "/bin"
    # the started command finds it set (or the user opted out): no second start
    for done in (new_env, {**env, "LUNAR_DRAKE_MALLOC": "default"}):
        assert not reexec_with_malloc_tunables(environ=done, execv=lambda *a: calls.append(a))
    assert len(calls) == 1


@pytest.mark.skipif(not ON_GLIBC, reason="glibc's tunables only")
def test_a_real_process_starts_again_with_it_and_its_output_and_status_survive():
    # "start" is printed only by a process that began with the tunable: the started one
    code = (
        "import os, sys; print('start', flush=True) if 'GLIBC_TUNABLES' in os.environ else None;"
        "from lunar_drake.allocator import reexec_with_malloc_tunables as r; r();"
        "print(os.environ['GLIBC_TUNABLES']); sys.exit(3)"
    )
    env = {k: v for k, v in os.environ.items() if k not in ("GLIBC_TUNABLES", "LUNAR_DRAKE_MALLOC")}
    proc = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True)
    assert proc.returncode == 3, proc.stderr
    assert proc.stdout.splitlines() == ["start", f"glibc.malloc.tcache_count={TCACHE_COUNT}"]


def test_an_unknown_choice_is_refused_in_one_line_with_status_2():
    with pytest.raises(ConfigError, match=r"LUNAR_DRAKE_MALLOC = 'fast'; choose one of"):
        tunables_to_set({"LUNAR_DRAKE_MALLOC": "fast"})
    assert tunables_to_set({"LUNAR_DRAKE_MALLOC": "tuned", "GLIBC_TUNABLES": "a=1"}) in (
        None,  # not glibc
        f"a=1:glibc.malloc.tcache_count={TCACHE_COUNT}",
    )
    env = {**os.environ, "LUNAR_DRAKE_MALLOC": "fast"}
    env.pop("GLIBC_TUNABLES", None)
    proc = subprocess.run(
        [sys.executable, "-m", "lunar_drake.cli", "--help"], env=env, capture_output=True, text=True
    )
    assert proc.returncode == 2 and proc.stdout == ""
    assert proc.stderr.strip().splitlines() == [
        "lunar-drake: error: ConfigError: LUNAR_DRAKE_MALLOC = 'fast'; choose one of "
        "['tuned', 'default']"
    ]
