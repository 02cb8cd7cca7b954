"""The world SEAL predicts in: LIBERO tasks, exact snapshots, a parallel pool, rendering."""

from seal.sim import gl  # noqa: F401  (must run before mujoco is imported)
