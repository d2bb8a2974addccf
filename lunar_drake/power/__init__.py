"""Power core (numpy, no Drake): the solar array, the battery and the loads.

* :mod:`.solar_array` -- panel pose, Sun incidence, visible fraction of the solar disk
  over the terrain horizon at the panel's height, array power;
* :mod:`.battery` -- state of charge with charge/discharge efficiencies, clamped;
* :mod:`.loads` -- motors (mechanical power over an efficiency), holding and constant draws;
* :mod:`.config` -- :class:`~.config.PowerConfig`, one section per concept.
"""
