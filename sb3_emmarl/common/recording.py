"""Animated GIF / MP4 of one evaluation episode of a team."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import torch as th

from sb3_emmarl.common.evaluation import Predictor, is_centralized, make_eval_env


def record_episode(
    model: Predictor,
    path: str | Path,
    seed: int = 0,
    env_kwargs: dict[str, Any] | None = None,
    deterministic: bool = False,
    vec_normalize_path: str | None = None,
    fps: int = 10,
    frame_skip: int = 1,
) -> dict[str, Any]:
    """Play one episode with ``render_mode="rgb_array"`` and write it as a GIF (``.gif``) or an MP4 (``.mp4``).

    :param model: the team's model (anything with SB3's ``predict``)
    :param path: output file; the suffix picks the format
    :param seed: episode seed
    :param env_kwargs: the reserve's arguments
    :param deterministic: the most likely actions instead of sampled ones (see ``evaluate_team``)
    :param vec_normalize_path: ``VecNormalize`` statistics saved in training
    :param fps: frames per second of the animation
    :param frame_skip: keep one frame in ``frame_skip``
    :return: the episode's metrics
    """
    path = Path(path)
    if path.suffix not in (".gif", ".mp4"):
        raise ValueError(f"the recording must be a .gif or .mp4 file, got {str(path)!r}")
    if fps < 1 or frame_skip < 1:
        raise ValueError(f"fps and frame_skip must be >= 1, got {fps} and {frame_skip}")
    env_kwargs = {**dict(env_kwargs or {}), "render_mode": "rgb_array"}
    venv = make_eval_env(seed, env_kwargs, is_centralized(model, env_kwargs), vec_normalize_path, model)
    with th.random.fork_rng():
        th.manual_seed(seed)
        observations = venv.reset()
        frames = [venv.render()]
        state, starts, step, metrics = None, np.ones(venv.num_envs, dtype=bool), 0, None
        while metrics is None:
            actions, state = model.predict(observations, state=state, episode_start=starts, deterministic=deterministic)
            observations, _, starts, infos = venv.step(actions)
            step += 1
            if starts[0]:
                metrics = infos[0]["metrics"]
            elif step % frame_skip == 0:
                frames.append(venv.render())
    venv.close()
    path.parent.mkdir(parents=True, exist_ok=True)
    if path.suffix == ".gif":
        from PIL import Image

        images = [Image.fromarray(frame) for frame in frames]
        images[0].save(path, save_all=True, append_images=images[1:], duration=int(1000 / fps), loop=0, optimize=True)
    else:
        import imageio.v2 as imageio

        imageio.mimwrite(path, frames, fps=fps)
    return metrics
