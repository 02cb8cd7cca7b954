"""Motion primitives for articulated fixtures: drawers, the microwave door, the stove knob.

Each maps (scene, LIBERO name, sub-goal atom) to a `skills.Step`, reactively, like
`skills.pick`/`skills.place`.
"""

from __future__ import annotations

ARTICULATED_SKILLS: dict = {}
