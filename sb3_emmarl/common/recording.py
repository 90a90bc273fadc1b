"""One evaluation episode of a team: as an animated GIF / MP4, or as the paths of its UAVs and the poachers."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch as th

from sb3_emmarl.common.env_ids import ENV_ID
from sb3_emmarl.common.evaluation import Predictor, is_centralized, make_eval_env
from sb3_emmarl.common.trust.atomic_files import write_atomic
from sb3_emmarl.common.trust.extras import requires


def _play(model: Predictor, venv: Any, seed: int, deterministic: bool, observe: Callable[[int], Any]) -> dict[str, Any]:
    """Play the first episode of copy 0 with ``torch`` seeded by ``seed``; ``observe(step)`` is called after the reset
    (step 0) and after every step but the last (whose observation already belongs to the next episode).

    :return: the episode's metrics
    """
    with th.random.fork_rng():
        th.manual_seed(seed)
        observations = venv.reset()
        observe(0)
        state, starts, step, metrics = None, np.ones(venv.num_envs, dtype=bool), 0, None
        while metrics is None:
            actions, state = model.predict(observations, state=state, episode_start=starts, deterministic=deterministic)
            observations, _, starts, infos = venv.step(actions)
            step += 1
            if starts[0]:
                metrics = infos[0]["metrics"]
            else:
                observe(step)
    return metrics


def record_trajectory(model: Predictor, seed: int = 0, env_kwargs: dict[str, Any] | None = None,
                      deterministic: bool = False, vec_normalize_path: str | None = None) -> dict[str, Any]:
    """The paths of a team over one evaluation episode (the trajectory figures of the paper's Figures 10-12).

    :param model: a parameter-shared team's model
    :param seed: episode seed
    :param env_kwargs: the reserve's arguments
    :param deterministic: the most likely actions instead of sampled ones
    :param vec_normalize_path: ``VecNormalize`` statistics saved in training
    :return: ``positions`` ``(T, n_uavs, 2)`` (row, col), ``poachers`` ``(T, n_poachers, 2)`` (NaN while a poacher is
        not in play), ``terrain`` ``(height, width)`` and the episode's ``metrics``
    """
    from wildlife_reserve.reserve.kernels.constants import POACHER_ACTIVE

    if is_centralized(model, env_kwargs):
        raise ValueError("record_trajectory draws a parameter-shared team; this model acts on the centralised view")
    venv = make_eval_env(seed, env_kwargs, False, vec_normalize_path, model)
    inner = venv.unwrapped
    positions: list[np.ndarray] = []
    poachers: list[np.ndarray] = []

    def observe(_: int) -> None:
        uav_pos, poacher_pos, status = (inner.get_attr(name, indices=[0])[0]
                                        for name in ("uav_pos", "poacher_pos", "poacher_status"))
        positions.append(np.array(uav_pos, dtype=np.float64))
        poachers.append(np.where((status == POACHER_ACTIVE)[:, None], poacher_pos, np.nan).astype(np.float64))

    metrics = _play(model, venv, seed, deterministic, observe)
    terrain = np.array(inner.get_attr("terrain", indices=[0])[0])
    venv.close()
    return {"positions": np.stack(positions), "poachers": np.stack(poachers), "terrain": terrain, "metrics": metrics}


def record_episode(
    model: Predictor,
    path: str | Path,
    seed: int = 0,
    *,
    env_kwargs: dict[str, Any] | None = None,
    deterministic: bool = False,
    vec_normalize_path: str | None = None,
    fps: int = 10,
    frame_skip: int = 1,
    vec_env_wrapper: Callable[[Any], Any] | None = None,
    env_id: str = ENV_ID,
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
    :param vec_env_wrapper: the ``vec_env_wrapper`` the model was trained under, if any (see ``make_eval_env``)
    :param env_id: the environment (default the reserve)
    :return: the episode's metrics
    """
    path = Path(path)
    if path.suffix not in (".gif", ".mp4"):
        raise ValueError(f"the recording must be a .gif or .mp4 file, got {str(path)!r}")
    if fps < 1 or frame_skip < 1:
        raise ValueError(f"fps and frame_skip must be >= 1, got {fps} and {frame_skip}")
    env_kwargs = {**dict(env_kwargs or {}), "render_mode": "rgb_array"}
    venv = make_eval_env(seed, env_kwargs, is_centralized(model, env_kwargs, env_id), vec_normalize_path, model,
                         vec_env_wrapper, env_id)
    frames: list[np.ndarray] = []

    def keep_frame(step: int) -> None:
        if step % frame_skip == 0:
            frame = venv.render()
            assert frame is not None  # (render_mode="rgb_array")
            frames.append(frame)

    metrics = _play(model, venv, seed, deterministic, keep_frame)
    venv.close()
    path.parent.mkdir(parents=True, exist_ok=True)
    if path.suffix == ".gif":
        from PIL import Image

        images = [Image.fromarray(frame) for frame in frames]
        write_atomic(path, lambda file: images[0].save(file, format="GIF", save_all=True, append_images=images[1:],
                                                      duration=int(1000 / fps), loop=0, optimize=True))
    else:
        with requires("imageio", "render", "an MP4 recording"):
            import imageio.v3 as iio

        write_atomic(path, lambda file: iio.imwrite(file, np.stack(frames), extension=".mp4", fps=fps))
    return metrics
