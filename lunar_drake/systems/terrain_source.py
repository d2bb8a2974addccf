"""TerrainSource: the site's Heightfield as a Drake system output."""

from __future__ import annotations

from pydrake.common.value import AbstractValue

from lunar_drake.systems.leaf import Leaf
from lunar_drake.terrain.heightfield import Heightfield


class TerrainSource(Leaf):
    """Publishes the site terrain for every consumer (contact, renderer, science, maps).

    .. pydrake_system::

        name: TerrainSource
        output_ports:
        - heightfield

    The Heightfield (site frame: x east, y north, z up, metres, origin at the raster
    centre) is held as an abstract *parameter*, so a Context may carry a different
    terrain without rebuilding the diagram. The output is that parameter.
    """

    def __init__(self, *, heightfield: Heightfield):
        super().__init__()
        if not isinstance(heightfield, Heightfield):
            raise TypeError(f"heightfield must be a Heightfield, got {type(heightfield).__name__}")
        self._heightfield_index = self.DeclareAbstractParameter(AbstractValue.Make(heightfield))
        self.heightfield_output = self.DeclareAbstractOutputPort(
            "heightfield",
            lambda: AbstractValue.Make(heightfield),
            self._calc_heightfield,
            prerequisites_of_calc={self.all_parameters_ticket()},
        )

    def _calc_heightfield(self, context, output):
        output.set_value(context.get_abstract_parameter(self._heightfield_index).get_value())

    def get_heightfield(self, context) -> Heightfield:
        """The Heightfield in ``context`` (this system's context)."""
        return context.get_abstract_parameter(self._heightfield_index).get_value()

    def set_heightfield(self, context, heightfield: Heightfield) -> None:
        """Replaces the terrain in ``context``."""
        context.get_mutable_abstract_parameter(self._heightfield_index).set_value(heightfield)
