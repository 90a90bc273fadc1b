"""EM-PPO: parameter-shared PPO whose policy sees a categorical latent posterior fitted by Expectation-Maximization."""

from __future__ import annotations

from typing import Any, ClassVar, TypeVar

import numpy as np
from stable_baselines3 import PPO
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.type_aliases import GymEnv, Schedule

from sb3_emmarl.common.latent.algorithm import LatentAlgorithmMixin
from sb3_emmarl.common.latent.em import LatentBatch, transitions_from_rollout
from sb3_emmarl.em_ppo.policies import MlpPolicy

SelfEMPPO = TypeVar("SelfEMPPO", bound="EMPPO")


class EMPPO(LatentAlgorithmMixin, PPO):
    """EM-PPO (Taghavi & Farnoosh, "Latent Variable Modeling in Multi-Agent Reinforcement Learning via
    Expectation-Maximization for UAV-Based Wildlife Protection", Algorithm 2).

    PPO's policy and value networks see, beside the observation, the posterior ``q_phi(z | h_t)`` of a
    categorical latent variable with ``n_components`` components, inferred by a GRU from the agent's last
    ``history_length`` steps (a :class:`~sb3_emmarl.common.latent.history.HistoryWrapper` is added to the
    environment when it has none). After every ``e_step_interval`` rollouts the E-step fits the encoder and
    the decoder ``p(x_{t+1}, r_t | x_t, a_t, z)`` to the latest rollouts by maximising the ELBO and sets the
    prior ``pi`` to the mean responsibilities; PPO's update is the M-step. Works on any SB3 vector
    environment with flat ``Box`` observations; with the reserve's parameter-sharing vector environment
    every UAV's entry has its own history and posterior (decentralised execution).

    :param policy: ``"MlpPolicy"`` or a :class:`~sb3_emmarl.common.latent.policies.LatentActorCriticPolicy` subclass
    :param env: the environment (a ``VecEnv`` or a Gymnasium env)
    :param learning_rate: PPO's learning rate (or schedule)
    :param n_steps: steps per environment per rollout
    :param batch_size: PPO minibatch size
    :param n_epochs: PPO epochs per rollout
    :param gamma: discount factor
    :param gae_lambda: GAE lambda
    :param clip_range: PPO clipping (or schedule)
    :param ent_coef: entropy coefficient
    :param n_components: ``K``, components of the latent variable
    :param history_length: ``H``, steps of history the encoder reads
    :param encoder_hidden: GRU hidden size of the encoder
    :param decoder_hidden: hidden layer sizes of the decoder
    :param estimator: ELBO estimator, ``"enumerate"`` (exact over ``K``) or ``"gumbel"`` (annealed Gumbel-softmax)
    :param team_pooling: in the E-step, pool the agents of one reserve copy and step into a team posterior
        (centralised training; execution stays decentralised)
    :param e_step_interval: rollouts between E-steps
    :param e_step_kwargs: overrides of :data:`~sb3_emmarl.common.latent.algorithm.E_STEP_DEFAULTS`
        (``learning_rate``, ``n_epochs``, ``batch_size``, ``window``, ``temperature``, ``min_temperature``,
        ``anneal_rate``, ``max_samples``, ``starved_share``)
    :param use_latent: False is the no-latent ablation (same networks without the posterior input, no E-step)
    :param freeze_e_step: ablation: the encoder, decoder and prior never change
    :param freeze_m_step: ablation: the policy and value networks never change (the paper's "disabling the M-step")
    :param policy_kwargs: policy arguments (``net_arch``, ...)
    :param tensorboard_log: tensorboard folder
    :param verbose: verbosity
    :param seed: seed
    :param device: torch device
    :param _init_setup_model: build the networks now
    :param kwargs: other PPO arguments
    """

    policy_aliases: ClassVar[dict[str, type[BasePolicy]]] = {"MlpPolicy": MlpPolicy}

    def __init__(
        self,
        policy: str | type[MlpPolicy],
        env: GymEnv | str | None,
        learning_rate: float | Schedule = 3e-4,
        n_steps: int = 128,
        batch_size: int = 1280,
        n_epochs: int = 5,
        gamma: float = 0.99,
        gae_lambda: float = 0.95,
        clip_range: float | Schedule = 0.2,
        ent_coef: float = 0.01,
        n_components: int = 4,
        history_length: int = 8,
        encoder_hidden: int = 32,
        decoder_hidden: tuple[int, ...] = (64, 64),
        estimator: str = "enumerate",
        team_pooling: bool = False,
        e_step_interval: int = 4,
        e_step_kwargs: dict[str, Any] | None = None,
        use_latent: bool = True,
        freeze_e_step: bool = False,
        freeze_m_step: bool = False,
        policy_kwargs: dict[str, Any] | None = None,
        tensorboard_log: str | None = None,
        verbose: int = 0,
        seed: int | None = None,
        device: str = "auto",
        _init_setup_model: bool = True,
        **kwargs: Any,
    ) -> None:
        env, policy_kwargs = self._init_latent(env, history_length, n_components, encoder_hidden, decoder_hidden,
                                               use_latent, freeze_e_step, freeze_m_step, estimator, team_pooling,
                                               e_step_interval, e_step_kwargs, policy_kwargs, verbose)
        super().__init__(policy, env, learning_rate=learning_rate, n_steps=n_steps, batch_size=batch_size,
                         n_epochs=n_epochs, gamma=gamma, gae_lambda=gae_lambda, clip_range=clip_range, ent_coef=ent_coef,
                         policy_kwargs=policy_kwargs, tensorboard_log=tensorboard_log, verbose=verbose, seed=seed,
                         device=device, _init_setup_model=False, **kwargs)
        if _init_setup_model:
            self._setup_model()

    def _setup_model(self) -> None:
        super()._setup_model()
        self._setup_e_step()
        # The posterior each rollout step's actions were drawn with, and which steps have theirs.
        self._rollout_posteriors = np.zeros((self.n_steps, self.n_envs, self.n_components), dtype=np.float32)
        self._recorded = np.zeros(self.n_steps, dtype=bool)

    def _excluded_save_params(self) -> list[str]:
        return [*super()._excluded_save_params(), "_rollout_posteriors", "_recorded"]

    def start_collection(self) -> None:
        self._recorded[:] = False

    def record_collection_step(self) -> None:
        """Keep the posterior the policy computed for this step's actions (read from its features extractor)."""
        extractor = self.policy.pi_features_extractor
        posterior, extractor.latest_posterior = extractor.latest_posterior, None
        step = self.rollout_buffer.pos  # the row the step is about to be added at
        if posterior is not None and step < self.n_steps and posterior.shape == self._rollout_posteriors.shape[1:]:
            self._rollout_posteriors[step] = posterior.cpu().numpy()
            self._recorded[step] = True

    def latent_batch(self) -> LatentBatch:
        """The E-step's data from the rollout buffer just collected."""
        buffer = self.rollout_buffer
        return transitions_from_rollout(self.layout, buffer.observations, buffer.episode_starts, self.agents_per_copy,
                                        self.device)

    def train(self) -> None:
        """The M-step: PPO's update (skipped when ``freeze_m_step``).

        The policy and value networks see the posteriors the rollout's actions were drawn with (the encoder
        the E-step just refitted acts from the next rollout on), so PPO's ratios start at 1 as they should.
        Each is written over the start of its (already used) history window in the buffer, and the epochs of
        minibatches read it there instead of running the encoder again. Steps collected without the EM
        callback get theirs from the current encoder.
        """
        if self.freeze_m_step:
            self._update_learning_rate(self.policy.optimizer)
            self.logger.record("train/m_step_frozen", 1.0)
            return
        latent = self.policy.latent_model
        if latent is None:
            super().train()
            return
        observations = self.rollout_buffer.observations
        recorded = self._recorded.all() and observations.shape[:2] == self._rollout_posteriors.shape[:2]
        self.write_posterior(observations, self._rollout_posteriors if recorded else
                             self.posterior(observations.reshape(-1, observations.shape[-1])).reshape(
                                 *observations.shape[:-1], self.n_components))
        latent.precomputed = True
        try:
            super().train()
        finally:
            latent.precomputed = False

    def learn(self: SelfEMPPO, total_timesteps: int, callback: BaseCallback | list | None = None, log_interval: int = 1,
              tb_log_name: str = "EMPPO", reset_num_timesteps: bool = True, progress_bar: bool = False) -> SelfEMPPO:
        return super().learn(total_timesteps, callback=self._with_em_callback(callback), log_interval=log_interval,
                             tb_log_name=tb_log_name, reset_num_timesteps=reset_num_timesteps, progress_bar=progress_bar)
