import numpy as np

from seal.benchmarks.sim import psnr
from seal.sim.world import LiberoWorld


def test_fast_render_mode_is_close_to_stock_and_leaves_physics_alone(world):
    fast = LiberoWorld(("libero_10", 0), render_mode="fast")
    try:
        world.reset(0)
        fast.reset(0)
        assert fast.snapshot() == world.snapshot()  # same physics, only the drawing differs
        actions = np.random.default_rng(3).uniform(-1, 1, (15, 7))
        world.step_chunk(actions)
        fast.step_chunk(actions)
        assert fast.snapshot() == world.snapshot()
        a, b = world.observe(), fast.observe()
        assert a.agent.shape == b.agent.shape == (224, 224, 3)
        assert not np.array_equal(a.agent, b.agent)  # it really is a different render model
        assert psnr(a.agent, b.agent) > 26 and psnr(a.wrist, b.wrist) > 26
        from seal.sim.render import drawn_faces

        assert drawn_faces(fast.render_model) < 0.35 * drawn_faces(world.model)
    finally:
        fast.close()


def test_renders_stay_right_when_another_renderer_is_closed(world):
    """Several worlds' renderers in one process. Closing one world's renderers while another
    world's GL context is current must not free that other world's buffers (mujoco's
    Renderer.close frees in whichever context is current); and a world keeps one renderer per
    size, each drawing every new state anew."""
    fast = LiberoWorld(("libero_10", 0), render_mode="fast")
    other = LiberoWorld(("libero_10", 0), render_mode="fast")
    try:
        world.reset(0)
        fast.reset(0)
        other.reset(0)
        world.observe()
        other.observe()
        before = fast.observe().agent  # fast's context is the current one now
        other.close()
        assert np.array_equal(fast.observe().agent, before)
        small = [world.render_raw(("agentview",), size=96)["agentview"]]
        world.observe()  # back to the 256 renderer, then to the 96 one again
        world.step_chunk(np.random.default_rng(4).uniform(-1, 1, (10, 7)))
        small.append(world.render_raw(("agentview",), size=96)["agentview"])
        assert psnr(small[0], small[1]) is not None and psnr(small[0], small[1]) < 40  # the arm moved
        assert small[0].std() > 10
    finally:
        fast.close()
        other.close()
