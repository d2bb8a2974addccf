"""Sensor models (numpy, no Drake): what each sensor measures, its noise and its timing.

Every sensor follows one pattern (DESIGN.md decision 6): a config dataclass with an
update rate ``rate_hz`` (samples at t_k = k / rate_hz from t = 0), a delivery delay
``delay_s`` (sample k is available at t_k + delay_s) and a noise model; sample k's noise
comes from ``rng.sample_generator(stream_key(seed, system_name), k)``. The Drake systems
in ``lunar_drake/systems/`` (one per sensor, on the base class
:class:`~lunar_drake.systems.sampled_sensor.SampledSensor`) call these functions.

Frames: W the site frame (x east, y north, z up), B a body, S the sensor frame fixed in B
(pose ``X_BS``). Units: SI (m, s, rad) unless a name says otherwise.
"""
