"""SampledSensor: the one pattern every plant sensor follows (rate, delay, noise stream)."""

from __future__ import annotations

import numpy as np
from pydrake.systems.framework import BasicVector

from lunar_drake.rng import SampleStream, stream_key
from lunar_drake.sensors.sampling import (
    check_sampling,
    delivered_index,
    sample_index,
    samples_in_flight,
)
from lunar_drake.systems.leaf import Leaf


class SampledSensor(Leaf):
    """Base class of the plant's vector sensors.

    Sample k is taken at t_k = k / rate_hz (k = 0, 1, ...) by :meth:`sample`, from the
    inputs and from a numpy Generator for that sample,
    ``rng.sample_generator(stream_key(seed, name), k)``, and is delivered at
    t_k + delay_s: the output at time t is the latest sample with t_k + delay_s <= t, or
    ``initial`` before the first. Samples in flight are discrete state (a shift register
    of :func:`~lunar_drake.sensors.sampling.samples_in_flight` samples plus the index of
    the newest), so the sensor holds nothing outside its Context and the output never
    feeds through from the inputs (sensors can close loops). Same seed, name and inputs
    give bit-identical outputs.

    Subclasses declare their inputs (and any extra state, e.g. a bias) and implement
    ``sample(context, generator, discrete_state) -> np.ndarray``.
    """

    def __init__(
        self,
        *,
        name: str,
        seed: int,
        rate_hz: float,
        delay_s: float,
        initial,
        output_name: str,
    ):
        super().__init__()
        check_sampling(rate_hz, delay_s)
        self.set_name(name)
        self._key = stream_key(seed, name)
        self._stream = SampleStream(self._key)  # scratch, re-keyed per sample
        self._rate = float(rate_hz)
        self._delay = float(delay_s)
        initial = np.asarray(initial, dtype=np.float64).ravel()
        self._size = initial.size
        self._initial = initial
        self._depth = samples_in_flight(rate_hz=self._rate, delay_s=self._delay)
        self._samples = self.DeclareDiscreteState(BasicVector(np.tile(initial, self._depth)))
        self._newest = self.DeclareDiscreteState(BasicVector([-1.0]))
        self.DeclarePeriodicDiscreteUpdateEvent(1.0 / self._rate, 0.0, self._on_sample)
        if self._depth == 1:
            self.measurement_output = self.DeclareStateOutputPort(output_name, self._samples)
        else:
            self.measurement_output = self.DeclareVectorOutputPort(
                output_name,
                BasicVector(self._size),
                self._calc_delivered,
                prerequisites_of_calc={self.time_ticket(), self.xd_ticket()},
            )

    @property
    def rate_hz(self) -> float:
        """Sample rate (Hz)."""
        return self._rate

    @property
    def delay_s(self) -> float:
        """Delivery delay (s)."""
        return self._delay

    def sample(self, context, generator: np.random.Generator, discrete_state) -> np.ndarray:
        """One measurement from the current inputs (override)."""
        raise NotImplementedError

    def _on_sample(self, context, discrete_state):
        k = sample_index(context.get_time(), self._rate)
        value = np.asarray(self.sample(context, self._stream.at(k), discrete_state), np.float64)
        if self._depth == 1:
            discrete_state.set_value(self._samples, value)
        else:
            old = context.get_discrete_state(self._samples).get_value()
            buf = np.empty_like(old)
            buf[: self._size] = value
            buf[self._size :] = old[: -self._size]
            discrete_state.set_value(self._samples, buf)
        discrete_state.set_value(self._newest, [float(k)])

    def _calc_delivered(self, context, output):
        k = delivered_index(context.get_time(), rate_hz=self._rate, delay_s=self._delay)
        if k < 0:
            output.SetFromVector(self._initial)
            return
        newest = int(context.get_discrete_state(self._newest).GetAtIndex(0))
        lag = min(max(newest - k, 0), self._depth - 1)
        buf = context.get_discrete_state(self._samples).get_value()
        output.SetFromVector(buf[lag * self._size : (lag + 1) * self._size])
