"""The process-wide allocator tuning (raycast.tune_malloc_for_large_arrays).

Each case runs in a fresh interpreter (the tuning is process-wide and happens once) and
counts the page faults of a frame-like allocation pattern: six 5 MB buffers written and
freed, five times over."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap

PROBE = textwrap.dedent(
    """
    import json, resource, sys
    import numpy as np
    from lunar_drake.render import raycast

    tuned = raycast.tune_malloc_for_large_arrays() if sys.argv[1] == "tune" else None

    def frame():
        bufs = [np.empty(5 * 2**20 // 4, np.float32) for _ in range(6)]
        for b in bufs:
            b.fill(1.0)

    frame()
    f0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    for _ in range(5):
        frame()
    faults = resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f0
    print(json.dumps({"tuned": tuned, "again": raycast.tune_malloc_for_large_arrays(),
                      "faults": faults}))
    """
)


def _probe(mode: str, **env) -> dict:
    e = {k: v for k, v in os.environ.items() if not k.startswith("MALLOC_")}
    e.update(env)
    out = subprocess.run(
        [sys.executable, "-c", PROBE, mode], env=e, capture_output=True, text=True, check=True
    )
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_the_tuning_recycles_freed_frames_and_respects_the_environment():
    tuned = _probe("tune")
    untuned = _probe("none")
    # glibc's own thresholds, made explicit: the environment's choice stands
    env = _probe("tune", MALLOC_TRIM_THRESHOLD_="131072")
    assert tuned["tuned"] is True and tuned["again"] is True
    assert untuned["tuned"] is None and untuned["again"] is True  # asked at the end
    assert env["tuned"] is False and env["again"] is False
    assert _probe("tune", MALLOC_MMAP_THRESHOLD_="131072")["tuned"] is False
    # 150 MB written into recycled memory: pages fault in once, not every frame
    assert untuned["faults"] > 1000 and env["faults"] > 1000, (untuned, env)
    assert tuned["faults"] < untuned["faults"] / 10, (tuned, untuned)
