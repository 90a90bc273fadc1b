"""Environment copies are checked against the machine's memory before they are built (issue 65, item 5)."""

import numpy as np
import pytest

from sb3_emmarl.common.vec_env import make_vec_env, memory
from wildlife_reserve.reserve.reserve import ReserveParallelEnv


class Holder:
    __slots__ = ("array", "nested")

    def __init__(self, array, nested):
        self.array, self.nested = array, nested


def test_array_bytes_counts_each_base_array_once():
    base = np.zeros((100, 10))  # 8,000 bytes
    other = np.ones(50, dtype=np.int16)  # 100 bytes
    obj = Holder(base, {"view": base[3], "again": [base, (other, other[:10])], "text": "x" * 10_000})
    assert memory.array_bytes(obj) == 8_100
    assert memory.array_bytes([obj, obj]) == 8_100


def test_a_reserve_measures_what_its_arrays_hold():
    small, large = (ReserveParallelEnv(n_uavs=n, grid_size=side) for n, side in ((2, 20), (20, 200)))
    assert 0 < memory.array_bytes(small) < memory.array_bytes(large)
    assert memory.array_bytes(large) >= 20 * 200 * 200 * 2 * 2  # (two int16 time stamps per UAV and cell)


def test_copies_that_do_not_fit_are_refused_before_they_are_built(monkeypatch):
    built = []
    real = ReserveParallelEnv.__init__

    def counting(self, *args, **kwargs):
        built.append(1)
        real(self, *args, **kwargs)

    monkeypatch.setattr(ReserveParallelEnv, "__init__", counting)
    kwargs = {"n_uavs": 2, "grid_size": 20, "max_cycles": 40}
    one = memory.array_bytes(ReserveParallelEnv(**kwargs)) * memory.RESET_GROWTH
    built.clear()
    monkeypatch.setattr(memory, "available_memory", lambda: int(one * 8.5))
    make_vec_env(8, seed=0, env_kwargs=kwargs).close()
    built.clear()
    with pytest.raises(ValueError, match=r"^9 copies of this environment need about .* GiB \(\d+ MiB each\) and this "
                                         r"machine has .* GiB available: use fewer copies \(n_envs\)"):
        make_vec_env(9, seed=0, env_kwargs=kwargs)
    assert len(built) == 1  # the prototype only
    monkeypatch.setattr(memory, "available_memory", lambda: None)  # (unknown: not checked)
    make_vec_env(9, seed=0, env_kwargs=kwargs).close()


def test_available_memory_is_what_the_machine_reports():
    available = memory.available_memory()
    assert available is None or 0 < available
