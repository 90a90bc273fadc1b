"""The environments' evidence as plug-ins of the latent model (``common/latent/evidence.py``), and models saved before.

``data/em_ppo_0_21_0.zip`` is an EM-PPO saved by sb3-emmarl 0.21.0 (before the plug-ins): 200 agent-steps on a reserve of
2 UAVs on 20 x 20, 20 steps an episode, ``n_steps=100, batch_size=64, n_epochs=2, decoder_hidden=(8,),
policy_kwargs={"net_arch": [8]}, seed=0`` (its E-step holds the reading counts; SB3's members, deflated to keep it small).
"""

import ast
import re
from pathlib import Path

import numpy as np
import pytest

from sb3_emmarl import EMPPO
from sb3_emmarl.common.appended.wrapping import find_wrapper
from sb3_emmarl.common.latent.belief import BeliefWrapper
from sb3_emmarl.common.latent.evidence import (
    PLUGINS,
    GenericEvidence,
    evidence_from_spec,
    evidence_of,
    observation_size,
    register_evidence,
)
from sb3_emmarl.common.vec_env import make_vec_env

DATA = Path(__file__).parent / "data"
#: The reserve the saved model was trained on.
TINY = {"n_uavs": 2, "grid_size": 20, "max_cycles": 20}
#: What 0.21.0 predicted with the saved model, deterministically, over the first six steps of the reserve of seed 0
#: (the belief carried in ``state``), and the two UAVs' evidence per component after them.
SAVED_ACTIONS = [[14, 9], [14, 14], [6, 14], [9, 6], [9, 9], [9, 9]]
SAVED_EVIDENCE = [[-742.4769285065754, -657.7297416281575, -714.8286995883109, -713.2980385114427],
                  [-684.5819969870273, -638.643938197482, -686.2381928734687, -645.5469206258974]]


def test_a_model_saved_by_0_21_0_loads_and_predicts_as_it_did():
    model = EMPPO.load(DATA / "em_ppo_0_21_0.zip")
    assert model.evidence_spec["kind"] == "reserve" and model.policy.latent_model.has_counts
    assert model.e_step is not None and len(model.e_step.count_table["ids"]) > 0  # the E-step's counts came back
    env = make_vec_env(1, seed=0, env_kwargs=TINY)
    obs, state, starts, actions = env.reset(), None, np.ones(env.num_envs, dtype=bool), []
    for _ in range(len(SAVED_ACTIONS)):
        action, state = model.predict(obs, state=state, episode_start=starts, deterministic=True)
        actions.append(action.tolist())
        obs, _, starts, _ = env.step(action)
    assert actions == SAVED_ACTIONS
    np.testing.assert_allclose(np.asarray(state)[:, :4], SAVED_EVIDENCE, rtol=1e-9)


# ---------------------------------------------------------------------------------------------- the plug-ins
LATENT = Path(__file__).parents[1] / "sb3_emmarl" / "common" / "latent"
EM_PAGE = Path(__file__).parents[1] / "docs" / "em.md"


@pytest.fixture
def plugins():
    """The registry as it was before the test (a plug-in a test registers must not read other tests' environments)."""
    saved = dict(PLUGINS)
    yield PLUGINS
    PLUGINS.clear()
    PLUGINS.update(saved)


def test_the_generic_latent_package_imports_nothing_of_an_environment():
    """``common/latent`` reads environments only through their plug-ins (which live beside it): no other module of it
    imports the environment package or a plug-in, and none reads the reserve's constants (its window channels)."""
    for path in sorted(set(LATENT.glob("*.py")) - {LATENT / "reserve_evidence.py", LATENT / "zone_evidence.py"}):
        tree = ast.parse(path.read_text())
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom | ast.Import):
                names = [node.module or ""] if isinstance(node, ast.ImportFrom) else [a.name for a in node.names]
                for name in names:
                    assert not name.startswith(("wildlife_reserve", "sb3_emmarl.common.latent.reserve_evidence",
                                                 "sb3_emmarl.common.latent.zone_evidence")), f"{path.name} imports {name}"
            if isinstance(node, ast.Name | ast.alias):
                name = node.id if isinstance(node, ast.Name) else node.name
                assert not name.startswith("CH_"), f"{path.name} reads the reserve's constant {name}"


def test_each_environment_gets_its_plug_in_and_the_others_the_default():
    from stable_baselines3.common.env_util import make_vec_env as sb3_make_vec_env

    from sb3_emmarl.common.latent.reserve_evidence import ReadingCounter, ReserveEvidence
    from sb3_emmarl.common.latent.zone_evidence import ZoneEvidence
    from sb3_emmarl.common.mode_tasks import ModeCueEnv
    from wildlife_reserve import zone_patrol_v0

    reserve = evidence_of(make_vec_env(1, seed=0, env_kwargs=TINY))
    assert isinstance(reserve, ReserveEvidence) and isinstance(reserve.counts, ReadingCounter)
    assert (reserve.feature_dim, reserve.counts.n_channels, reserve.counts.weight) == (37, 3, 1 / 3)
    zones = evidence_of(make_vec_env(1, seed=0, env_fn=zone_patrol_v0.parallel_env, vec_env_type="batched"))
    assert isinstance(zones, ZoneEvidence) and zones.counts is None
    generic = evidence_of(sb3_make_vec_env(ModeCueEnv, n_envs=1))
    assert isinstance(generic, GenericEvidence) and generic.counts is None and generic.feature_dim == 4
    for evidence in (reserve, zones, generic):  # what a saved model rebuilds
        again = evidence_from_spec(evidence.spec)
        assert type(again) is type(evidence) and again.feature_dim == evidence.feature_dim
    # a reserve model saved before the count model: its specification has no grid, hence no counts
    old = evidence_from_spec({key: value for key, value in reserve.spec.items() if key != "grid"})
    assert isinstance(old, ReserveEvidence) and old.counts is None


def test_a_plug_in_is_refused_without_a_kind_and_a_kind_is_one_plug_in_s(plugins):
    with pytest.raises(TypeError, match="LatentEvidence subclass with a kind"):
        register_evidence(object)
    taken = re.escape("'reserve' is sb3_emmarl.common.latent.reserve_evidence.ReserveEvidence's already")
    with pytest.raises(ValueError, match=taken):
        register_evidence(type("Other", (GenericEvidence,), {"kind": "reserve"}))
    with pytest.raises(ValueError, match="needs a specification of kind 'generic', got 'zones'"):
        GenericEvidence({"kind": "zones", "obs_dim": 3})


def docs_example() -> str:
    section = EM_PAGE.read_text().split("### Your own evidence", 1)[1]
    return section.split("```python\n", 1)[1].split("```", 1)[0]


def test_the_method_page_s_plug_in_runs_as_written_and_its_model_loads(plugins, tmp_path, capsys):
    code = docs_example()
    assert len(code.strip().splitlines()) <= 30 and "@register_evidence" in code
    scaled, n = re.subn(r"total_timesteps=[0-9_]+", "total_timesteps=256", code)
    assert n == 1, "the example must give its budget as total_timesteps=<number>, once"
    namespace: dict = {"__name__": "em_page_example"}
    exec(compile(scaled, str(EM_PAGE), "exec"), namespace)
    assert capsys.readouterr().out.strip() == "{'kind': 'cue', 'obs_dim': 4}"
    model = namespace["model"]
    assert "latent/log_likelihood" in model.logger.name_to_value  # an E-step ran on the plug-in's features
    model.save(tmp_path / "cue")
    loaded = EMPPO.load(tmp_path / "cue")
    assert type(evidence_from_spec(loaded.evidence_spec)).__name__ == "CueEvidence"
    obs = np.eye(4, dtype=np.float32)
    np.testing.assert_array_equal(loaded.predict(obs, deterministic=True)[0], model.predict(obs, deterministic=True)[0])
    PLUGINS.pop("cue")
    with pytest.raises(ValueError, match=r"kind must be .* or 'generic', got 'cue'"):
        EMPPO.load(tmp_path / "cue")


class CueCounts:
    """:class:`~sb3_emmarl.common.latent.evidence.CountEvidence` of ModeCueEnv: each step's cue counted in its bin
    (one channel, a bin per mode), every bin seen once a step."""

    n_channels, n_rings, weight = 1, 1, 0.5

    def __init__(self, n_bins: int) -> None:
        self.n_bins = n_bins

    def statistics(self, observations: np.ndarray) -> np.ndarray:
        """``(n, 2, bins)``: exposures, then counts."""
        cue = np.asarray(observations, dtype=np.float64)[:, :self.n_bins]
        return np.stack([np.ones_like(cue), cue], axis=1)

    def grouped(self, observations, groups, n_groups=None, out=None):
        groups = np.asarray(groups)
        if out is None:
            out = np.zeros((n_groups if n_groups is not None else int(groups.max()) + 1, 2, self.n_bins))
        np.add.at(out, groups[groups >= 0], self.statistics(observations)[groups >= 0])
        return out

    def log_likelihood(self, observations, table):
        return np.einsum("ncb,cbk->nk", self.statistics(observations), table)


def test_a_plug_in_s_counts_enter_the_beliefs_and_the_e_step(plugins):
    """A plug-in with counts gets the count term: the E-step fits its rates from the plug-in's statistics, and each
    belief adds ``weight`` times the count log-likelihood of every new observation."""
    import torch as th
    from stable_baselines3.common.env_util import make_vec_env as sb3_make_vec_env

    from sb3_emmarl.common.mode_tasks import ModeCueEnv

    @register_evidence
    class CountedCue(GenericEvidence):
        kind = "counted_cue"

        def __init__(self, spec):
            super().__init__(spec)
            self.counts = CueCounts(self.obs_dim)

        @classmethod
        def from_env(cls, venv):
            return cls({"kind": cls.kind, "obs_dim": observation_size(venv)}) if venv.has_attr("cue_accuracy") else None

    env = sb3_make_vec_env(ModeCueEnv, n_envs=4, seed=0, env_kwargs={"cue_accuracy": 0.9})
    model = EMPPO("MlpPolicy", env, n_steps=32, batch_size=64, n_epochs=1, seed=0,
                  latent_kwargs=dict(likelihood_temperature=1e-6))
    latent = model.policy.latent_model
    assert (model.latent_layout.count_channels, model.latent_layout.count_bins) == (1, 4) and latent.has_counts
    assert model.e_step.count_weight == 0.5
    start = latent.count_log_rates.clone()
    model.learn(256)
    assert len(model.e_step.count_table["ids"]) > 0 and not th.equal(latent.count_log_rates, start)
    # the beliefs: the counts' evidence (the transitions' is tempered away), step by step
    venv = model.get_env()
    obs_dim = model.latent_layout.obs_dim
    venv.reset()
    expected = np.zeros((venv.num_envs, latent.n_components))
    with th.no_grad():
        table = th.cat([-latent.count_log_rates.exp().sum(1, keepdim=True), latent.count_log_rates], 1)
    for _ in range(5):  # within one episode (32 steps)
        following = venv.step(np.zeros(venv.num_envs, dtype=np.int64))[0][:, :obs_dim]
        expected += 0.5 * CueCounts(4).log_likelihood(following, table.double().permute(1, 2, 0).numpy())
    np.testing.assert_allclose(find_wrapper(venv, BeliefWrapper).tracker.evidence, expected, rtol=1e-4, atol=1e-3)


# ---------------------------------------------------------------------------------------------- REVIEW 4
def test_no_module_reads_torch_s_private_version_counter():
    for path in sorted((Path(__file__).parents[1] / "sb3_emmarl").rglob("*.py")):
        tree = ast.parse(path.read_text())
        assert not any(isinstance(node, ast.Attribute) and node.attr == "_version" for node in ast.walk(tree)), path


def test_the_beliefs_copy_of_the_model_follows_every_write_the_package_makes():
    """The lean copy (``StepLikelihood``) refreshes when the model's own version changes: after an E-step (its first
    deviations, its optimizer's steps, the count rates, the prior, a split), a load, a tensor replaced; and is kept
    while nothing was written."""
    import torch as th

    from sb3_emmarl.common.latent.em import EpisodeCounts, EStep, Transitions
    from sb3_emmarl.common.latent.layout import LatentLayout
    from sb3_emmarl.common.latent.model import LatentModel, StepLikelihood

    th.manual_seed(0)
    layout = LatentLayout(obs_dim=4, feature_dim=3, action_dim=2, n_components=2, count_channels=1, count_bins=3)
    model, rng = LatentModel(layout), np.random.default_rng(0)
    fast = StepLikelihood(model)
    x, a, y = (rng.standard_normal((30, d)).astype(np.float32) for d in (3, 2, 3))
    counts, exposure = rng.poisson(1.0, (5, 3)).astype(np.float32), np.ones((5, 3), dtype=np.float32)

    def check() -> None:
        with th.no_grad():
            expected = model.transition_log_likelihood(th.as_tensor(x), th.as_tensor(a), th.as_tensor(y))
        np.testing.assert_allclose(fast.log_likelihood(x, a, y), expected.double().numpy(), rtol=1e-5, atol=1e-4)
        np.testing.assert_allclose(fast.prior(), model.log_prior.double().numpy(), atol=1e-7)
        log_rates = model.count_log_rates.double().numpy()[:, 0]  # (K, bins)
        np.testing.assert_allclose(fast.count_table[1], log_rates.T, atol=1e-6)

    check()
    version = model.version()
    assert model.version() == version  # nothing written: the copy is kept
    e_step = EStep(model, n_epochs=2, window=1, starved_share=0.6, count_weight=0.5)
    episodes = np.repeat(np.arange(5), 6)
    e_step.add(Transitions.from_numpy(x, a, y, episodes),
               EpisodeCounts(th.arange(5), th.as_tensor(counts), th.as_tensor(exposure)))
    e_step.step()
    assert model.version() != version
    check()
    version = model.version()
    model.load_state_dict(LatentModel(layout).state_dict())
    assert model.version() != version
    check()
    version = model.version()
    with th.no_grad():
        model.decoder_bias.data = th.zeros_like(model.decoder_bias)  # a tensor replaced
    assert model.version() != version
    check()


def test_the_package_s_plug_ins_are_asked_first_even_when_another_was_registered_before_them(plugins):
    from sb3_emmarl.common.latent.evidence import BUILTIN_PLUGINS, LatentEvidence, register_evidence, registered_plugins

    class Mine(LatentEvidence):
        kind = "mine"

    plugins.clear()  # (as in a fresh process where a user's plug-in is registered before any model is built)
    register_evidence(Mine)
    order = list(registered_plugins())
    assert order[-1] == "mine" and len(order) == len(BUILTIN_PLUGINS) + 1
    assert [plugins[kind].__name__ for kind in order[:-1]] == [target.split(":")[1] for target in BUILTIN_PLUGINS]
    assert list(registered_plugins()) == order  # (asked again: the same)
