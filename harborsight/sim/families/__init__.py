"""Scene families that look like real harbours (issue #26): a lake or river shore with private
docks and boat lifts, a marina with rows of pontoons and finger piers full of moored boats,
a commercial quay with its vehicles and people, and a fishing harbour.

They sit beside the five classic scenarios of :mod:`harborsight.sim.layout` and use its
builder, so the same rules hold: every part is a convex mesh in the world frame W, vessels are
``ship`` (1), everything solid that is not a vessel is ``obstacle`` (2): land, lawns, trees,
houses, cars, rip-rap, docks, pontoons, lift frames and canopies, port vehicles and people.
Boats sitting on a lift are ``ship``; seen from above under a canopy they are hidden by it,
as in the real photos.

Each family also draws its own look (:func:`sample_realistic_environment`): brown, green or
blue water of any turbidity, a consumer drone's camera (vignetting, white balance, JPEG, a
little motion blur), on top of the classic sun, sky, waves and haze. The classic scenarios
keep their draws, so datasets rendered before these families are reproduced exactly.

The parts: :mod:`~harborsight.sim.families.shore` (the lake or river shore),
:mod:`~harborsight.sim.families.marina`, :mod:`~harborsight.sim.families.working_harbours`
(the commercial quay and the fishing harbour), :mod:`~harborsight.sim.families.boats` (the
craft they moor and those under way), :mod:`~harborsight.sim.families.look` (water and
camera) and :mod:`~harborsight.sim.families._parts` (palettes, primitives and the placement
rules they share).
"""

from harborsight.sim.families._parts import keep_gap
from harborsight.sim.families.boats import (
    FISHING_HULLS,
    LEISURE_HULLS,
    add_barge,
    add_boats_under_way,
    add_fishing_boat,
    add_leisure_boat,
    add_tug,
    paint_leisure_vessel,
)
from harborsight.sim.families.look import sample_realistic_environment
from harborsight.sim.families.marina import (
    BERTH_VIEW_LANES,
    BERTH_VIEW_SHARE,
    DENSE_MARINA,
    SPARSE_MARINA,
    BerthView,
    MarinaLayout,
    add_pontoon_row,
    build_marina,
    draw_berth_view,
)
from harborsight.sim.families.shore import (
    PORT_DECK_Z_M,
    PORT_RAIL_HEIGHT_M,
    WOODED_SHARE,
    add_jetski_port,
    add_private_dock,
    add_shore,
    build_lakeshore,
)
from harborsight.sim.families.working_harbours import build_commercial_quay, build_fishing_harbour

__all__ = [
    "BERTH_VIEW_LANES", "BERTH_VIEW_SHARE", "DENSE_MARINA", "FISHING_HULLS", "LEISURE_HULLS",
    "PORT_DECK_Z_M", "PORT_RAIL_HEIGHT_M", "SPARSE_MARINA", "WOODED_SHARE", "BerthView",
    "MarinaLayout", "add_barge", "add_boats_under_way", "add_fishing_boat", "add_jetski_port",
    "add_leisure_boat", "add_pontoon_row", "add_private_dock", "add_shore", "add_tug",
    "build_commercial_quay", "build_fishing_harbour", "build_lakeshore", "build_marina",
    "draw_berth_view", "keep_gap", "paint_leisure_vessel", "sample_realistic_environment",
]
