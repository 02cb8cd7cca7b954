"""The one replay video of an executed trajectory.

Rendering stays out of the prediction hot path: an episode records only the winners' actions,
and its video is rendered afterwards by replaying them from the init state (restore and replay
are exact, so the replay is the episode). The world is either an `EnvPool` (slot 0; its world is
already built, so this costs only the renders) or a `LiberoWorld` (replay mode's evaluation world).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from seal.sim.observation import AGENT_CAMERA, IMAGE_SIZE, to_policy_image


def replay_video(world, init_index: int, actions, path: str | Path, *, every: int = 4,
                 size: int = IMAGE_SIZE) -> Path:
    """Replay ``actions`` from init state ``init_index`` and write one agent-view frame every
    ``every`` control steps (20 Hz control -> 20/every fps) to ``path`` (mp4)."""
    import imageio.v2 as imageio

    actions = np.asarray(actions, dtype=float).reshape(-1, 7)
    path = Path(path)
    is_pool = hasattr(world, "sync")  # an EnvPool; else a LiberoWorld

    def frame() -> np.ndarray:
        if is_pool:
            raw = world.render((AGENT_CAMERA,), slots=[0])[0][AGENT_CAMERA]
        else:
            raw = world.render_raw((AGENT_CAMERA,))[AGENT_CAMERA]
        return to_policy_image(raw, size)

    world.reset(init_index)
    with imageio.get_writer(path, fps=20 // every, macro_block_size=1) as video:
        video.append_data(frame())
        for i in range(0, len(actions), every):
            if is_pool:
                world.step({0: actions[i:i + every]})
            else:
                world.step_chunk(actions[i:i + every])
            video.append_data(frame())
    return path
