"""What an action means to LIBERO's controller (OSC on the end-effector pose, deltas in [-1, 1])."""

# How far the hand moves per control step per unit of translation action (measured: ~6 mm at 0.5),
# and how far it turns per unit of rotation action: for extrapolating a chunk, or for sizing a
# deliberate offset (the near misses of `seal verify from-demos --branches`).
METRES_PER_ACTION = 0.012
RADIANS_PER_ACTION = 0.09
