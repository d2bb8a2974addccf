"""FrameWriter: saves camera frames into the run directory as they are rendered."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from pydrake.systems.framework import EventStatus, LeafSystem


def write_png(path: Path, array: np.ndarray) -> None:
    """Writes an 8- or 16-bit single-channel PNG atomically (temp name, then rename)."""
    import cv2

    path = Path(path)
    tmp = path.with_name(f".{path.stem}.tmp-{os.getpid()}{path.suffix}")
    if not cv2.imwrite(str(tmp), np.ascontiguousarray(array)):
        raise OSError(f"could not write image {str(path)!r}")
    os.replace(tmp, path)


class FrameWriter(LeafSystem):
    """Writes each new frame of the named cameras: ``<name>_<index>.png`` (16-bit PNG of
    the raw 12-bit codes) and ``<name>_<index>_preview.png`` (8-bit), at ``rate_hz``.

    .. pydrake_system::

        name: FrameWriter
        input_ports:
        - frame_index
        - <name>.raw
        - <name>.preview
    """

    def __init__(self, *, names, out_dir, rate_hz: float, preview_image_type):
        super().__init__()
        from pydrake.common.value import AbstractValue

        self._names = list(names)
        self._dir = Path(out_dir)
        self._dir.mkdir(parents=True, exist_ok=True)
        self.frame_index_input = self.DeclareVectorInputPort("frame_index", 1)
        self.raw_inputs = {
            n: self.DeclareAbstractInputPort(
                f"{n}.raw", AbstractValue.Make(np.zeros((1, 1), np.uint16))
            )
            for n in self._names
        }
        self.preview_inputs = {
            n: self.DeclareAbstractInputPort(
                f"{n}.preview", AbstractValue.Make(preview_image_type())
            )
            for n in self._names
        }
        # Just after each camera update (same period, tiny offset).
        self.DeclarePeriodicPublishEvent(1.0 / rate_hz, 1e-6, self._publish)
        # Bookkeeping for the run summary only (the files are the real output).
        self.written: list[Path] = []
        self.frames_written: set[int] = set()

    def _publish(self, context):
        k = int(self.frame_index_input.Eval(context)[0])
        if k < 0:
            return EventStatus.DidNothing()
        for n in self._names:
            raw = self.raw_inputs[n].Eval(context)
            prev = self.preview_inputs[n].Eval(context).data[:, :, 0]
            p = self._dir / f"{n}_{k:06d}.png"
            write_png(p, raw)
            write_png(self._dir / f"{n}_{k:06d}_preview.png", prev)
            self.written.append(p)
        self.frames_written.add(k)
        return EventStatus.Succeeded()
