"""The renderer's process-wide allocator tuning (raycast.tune_malloc_for_large_arrays).

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

    if sys.argv[1] == "renderer":
        from lunar_drake.render.camera import CameraConfig, TerrainCameraRenderer
        from lunar_drake.terrain.heightfield import Heightfield

        hf = Heightfield.from_array(np.zeros((32, 32), np.float32), resolution_m=0.1)
        TerrainCameraRenderer(heightfield=hf, model=CameraConfig(width=64, height=48))
    tuned = raycast.tune_malloc_for_large_arrays()

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


def test_a_renderer_tunes_the_process_and_freed_frames_are_recycled():
    tuned = _probe("renderer")
    # glibc's own thresholds, made explicit: the environment's choice stands
    plain = _probe("renderer", MALLOC_TRIM_THRESHOLD_="131072")
    assert tuned["tuned"] is True and tuned["again"] is True
    assert plain["tuned"] is False and plain["again"] is False
    # 150 MB written into recycled memory: pages fault in once, not every frame
    assert plain["faults"] > 1000, plain
    assert tuned["faults"] < plain["faults"] / 10, (tuned, plain)


def test_the_tuning_alone_without_a_renderer():
    assert _probe("alone")["tuned"] is True
    assert _probe("alone", MALLOC_MMAP_THRESHOLD_="131072")["tuned"] is False
