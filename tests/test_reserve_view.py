"""The reserve's observation builder and renderer read it through :class:`~wildlife_reserve.reserve.view.ReserveView`,
its public read-only face: the reserve has every member of it, and neither module reads a private attribute of it."""

from __future__ import annotations

import ast
from pathlib import Path

import numpy as np
import pytest

from wildlife_reserve import reserve_v1
from wildlife_reserve.reserve import observation, rendering
from wildlife_reserve.reserve.view import ReserveView


@pytest.mark.parametrize("kwargs", [{}, {"compass": True, "agent_ids": True, "adversarial": True},
                                    {"compass": True, "strategy_zones": True, "n_leopards": 4}])
def test_a_reset_reserve_is_a_reserve_view_whose_grid_views_are_its_own_arrays(kwargs):
    env = reserve_v1.parallel_env(n_uavs=3, grid_size=20, belief_size=4, max_cycles=20, **kwargs)
    assert not isinstance(env, ReserveView)  # (before a reset there is no episode to read)
    env.reset(seed=3)
    assert isinstance(env, ReserveView)
    env.step({agent: 1 for agent in env.agents})
    assert np.array_equal(env.cells, np.floor(env.uav_pos).astype(np.int64))
    assert env.blocks.shape == (env.height, env.width) and env.blocks.max() == env.config.belief_size ** 2 - 1
    assert np.array_equal(env.inv_scale, 1.0 / np.array([env.height - 1, env.width - 1]))


@pytest.mark.parametrize("module", [observation, rendering], ids=lambda module: module.__name__.rpartition(".")[2])
def test_observation_and_rendering_read_no_private_attribute_of_another_object(module):
    tree = ast.parse(Path(module.__file__).read_text(encoding="utf-8"))
    private = [f"line {node.lineno}: {ast.unparse(node)}" for node in ast.walk(tree)
               if isinstance(node, ast.Attribute) and node.attr.startswith("_") and not node.attr.startswith("__")
               and not (isinstance(node.value, ast.Name) and node.value.id == "self")]
    assert not private, "private attributes read from outside their class:\n" + "\n".join(private)
