"""Observations equal the package's own camera path as openpi's LIBERO example drives it.

Every consumer of pixels (a pi0 server, a VLM verifier, the learned models, videos) sees what
`LiberoWorld.observe` returns, so it is held bit for bit to `seal.sim.package_path`: both
cameras, several LIBERO-10 tasks and episodes (fixtures that move per episode: tasks 3 and 9),
after the settle steps and after a few actions, and one Visual-Scene and one Visual-Viewpoint
task. A flip, collision geoms, another camera, texture or fixture placement all break equality.
"""

import numpy as np
import pytest

from seal.sim.package_path import package_frames
from seal.sim.suites import get_task
from seal.sim.world import LiberoWorld

ACTIONS = np.random.default_rng(5).uniform(-1, 1, (3, 7))


def _psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2))
    return float("inf") if mse == 0 else 10 * np.log10(255.0**2 / mse)


@pytest.mark.parametrize("suite,task_id,episode", [
    ("libero_10", 0, 0),
    ("libero_10", 3, 2),  # the cabinet and wine rack stand elsewhere in each episode
    ("libero_10", 9, 1),  # the microwave too
    ("libero_10", 5, 0),
    ("visual_scene", 3, 0),  # a ketchup bottle in place of the wine bottle
    ("visual_viewpoint", 1, 0),  # another room's background and an orbited camera
])
def test_observations_equal_the_package_path(suite, task_id, episode):
    task = get_task(suite, task_id)
    world = LiberoWorld(task)
    try:
        world.reset(episode)
        ours = [world.observe()]
        for action in ACTIONS:
            world.step(action)
            ours.append(world.observe())
        camera_pose = world.camera_pose
    finally:
        world.close()
    theirs = package_frames(task, episode, ACTIONS, camera_pose=camera_pose)
    for t, (o, p) in enumerate(zip(ours, theirs)):
        for view in ("agent", "wrist"):
            a, b = getattr(o, view), getattr(p, view)
            assert a.shape == b.shape == (224, 224, 3)
            assert np.array_equal(a, b), (f"{task.key} episode {episode} frame {t}: {view} view differs from the "
                                          f"package's ({_psnr(a, b):.1f} dB, max |diff| "
                                          f"{np.abs(a.astype(int) - b).max()})")
        np.testing.assert_array_equal(o.state, p.state)


def test_the_robot_is_drawn_in_the_upper_half_of_the_agent_view(world):
    """Orientation without a reference image: hide the robot's geoms, and the pixels that change
    (the robot) lie in the upper half of the policy's agent view, as in openpi's frames."""
    world.reset(0)
    with_robot = world.observe().agent
    model = world.model
    robot = np.array([model.body(int(model.geom_bodyid[g])).name.startswith(("robot0_", "gripper0_"))
                      for g in range(model.ngeom)])
    saved = model.geom_rgba.copy()
    try:
        model.geom_rgba[robot, 3] = 0.0
        without = world.observe().agent
    finally:
        model.geom_rgba[:] = saved
    rows, _ = np.nonzero(np.abs(with_robot.astype(int) - without).max(axis=2) > 30)
    assert rows.size > 500, "hiding the robot changed almost nothing: is it drawn at all?"
    assert np.median(rows) < 112, f"the robot's pixels centre on row {np.median(rows):.0f} of 224: upside down"


def test_collision_geoms_are_not_drawn(world):
    """Showing geom group 0 (collision meshes) changes the stock image: so it is really hidden."""
    world.reset(0)
    shown = world.observe().agent
    renderer = world._get_renderer(256)
    renderer._option.geomgroup[0] = 1
    try:
        with_collision = world.observe().agent
    finally:
        renderer._option.geomgroup[0] = 0
    assert _psnr(shown, with_collision) < 30
