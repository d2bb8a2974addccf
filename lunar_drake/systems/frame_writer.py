"""FrameWriter: saves camera frames into a directory as they are delivered."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import BasicVector

from lunar_drake.files import atomic_path
from lunar_drake.systems.leaf import Leaf


def write_png(path: Path, array: np.ndarray) -> None:
    """Writes an 8- or 16-bit single-channel PNG atomically (temporary name, rename)."""
    import cv2

    with atomic_path(path, what="image") as tmp:
        if not cv2.imwrite(str(tmp), np.ascontiguousarray(array)):
            raise OSError(f"could not encode image {str(path)!r}")


class FrameWriter(Leaf):
    """Writes each new frame of the named cameras: ``<name>_<index>.png`` (16-bit PNG of
    the raw 12-bit codes) and ``<name>_<index>_preview.png`` (8-bit).

    .. pydrake_system::

        name: FrameWriter
        input_ports:
        - frame_index
        - <name>.raw
        - <name>.preview
        output_ports:
        - frames_written

    It checks ``frame_index`` every ``period_s`` from ``offset_s`` (just after each
    frame is delivered) and writes a frame whose index it has not written yet. State
    (discrete): [last index written, frames written]; ``frames_written`` outputs the
    count. The files are the side effect of that update.
    """

    def __init__(self, *, names, out_dir, period_s: float, offset_s: float, preview_image_type):
        super().__init__()
        self._names = list(names)
        self._dir = Path(out_dir)
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
        self._state = self.DeclareDiscreteState(BasicVector([-1.0, 0.0]))
        self.DeclarePeriodicDiscreteUpdateEvent(period_s, offset_s, self._update)
        self.frames_written_output = self.DeclareVectorOutputPort(
            "frames_written",
            BasicVector(1),
            lambda c, o: o.SetFromVector(c.get_discrete_state(self._state).get_value()[1:]),
            prerequisites_of_calc={self.xd_ticket()},
        )

    def frames_written(self, context) -> int:
        """How many frames were written (in this system's context)."""
        return int(context.get_discrete_state(self._state).GetAtIndex(1))

    def _update(self, context, discrete_state):
        last, count = context.get_discrete_state(self._state).get_value()
        k = int(self.frame_index_input.Eval(context)[0])
        if k < 0 or k == int(last):
            return
        self._dir.mkdir(parents=True, exist_ok=True)
        for n in self._names:
            raw = self.raw_inputs[n].Eval(context)
            preview = self.preview_inputs[n].Eval(context).data[:, :, 0]
            write_png(self._dir / f"{n}_{k:06d}.png", raw)
            write_png(self._dir / f"{n}_{k:06d}_preview.png", preview)
        discrete_state.get_mutable_vector(self._state).SetFromVector([float(k), count + 1.0])
