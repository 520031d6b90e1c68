"""Reference signals and parameter schedules shared by every stcgym environment (defined in
:mod:`stcgym.envs.references`, :mod:`stcgym.envs.reference_specs` and
:mod:`stcgym.envs.schedules`, re-exported here).

Both kinds of object produce their values **for a vector of lanes** (the plants of a vector env;
a single env is one lane), with any per-episode state kept lane by lane inside the object:

* a :class:`Reference` is :meth:`~Reference.allocate`-d for ``B`` lanes, :meth:`reset_lanes
  <Reference.reset_lanes>` at the start of an episode of some lanes (random references draw from
  the generators handed over), and asked for ``r`` with :meth:`values(k, lanes)
  <Reference.values>` (``k`` one step per lane);
* a :class:`Schedule` is allocated for ``B`` lanes, reset with each lane's nominal parameter
  array (theta of a canonical plant, ``[A B]`` of a state-space plant, ``Theta`` of the static
  object) and asked for the parameters in force with :meth:`values(k, lanes)
  <Schedule.values>`; ``k`` never decreases within a lane's episode.
  :meth:`~Schedule.next_change` tells when a lane's parameters may change next, so a vector env
  re-reads only lanes whose parameters move.

The single-lane forms ``ref.reset(rng)``, ``ref(k)``, ``schedule.reset(nominal, rng)`` and
``schedule(k)`` are lane 0 of a one-lane object: the same code.

Randomness comes only from the generators handed over at reset (children of the environment's
``np_random``), so an episode is reproducible from its seed whatever happened before.

A user schedule subclasses :class:`Schedule` and implements :meth:`~Schedule.reset_lanes` and
:meth:`~Schedule.values` (see :class:`Ramp` for a short example); a user reference is most
easily a callable ``k -> r`` (:class:`CallableReference`).
"""

from __future__ import annotations

from stcgym.envs import reference_specs as _reference_specs
from stcgym.envs import references as _references
from stcgym.envs import schedules as _schedules
from stcgym.envs.reference_specs import *  # noqa: F403
from stcgym.envs.references import *  # noqa: F403
from stcgym.envs.schedules import *  # noqa: F403

__all__ = [*_references.__all__, *_reference_specs.__all__, *_schedules.__all__]
