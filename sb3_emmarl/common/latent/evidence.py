"""What an environment gives the latent model to read: its evidence of the hidden mode, as a plug-in.

The latent model reads two kinds of evidence:

- **features** ``x`` of each observation, whose transitions ``p(x_{t+1} | x_t, a_t, z)`` the decoder models
  (:mod:`~sb3_emmarl.common.latent.model`); every environment has them;
- optionally **counts**: readings counted by bin with each bin's exposure, whose mixture of Poisson rates
  (:mod:`~sb3_emmarl.common.latent.counts`) says *where* something was read, which features summed over a window
  cannot (:class:`CountEvidence`).

An environment's plug-in is a :class:`LatentEvidence` subclass registered with :func:`register_evidence`:
:meth:`~LatentEvidence.from_env` recognises the environment and records what the plug-in needs as plain values
(its :attr:`~LatentEvidence.spec`, saved with a model), ``__init__`` builds the plug-in from them, so that a loaded
model reads observations as it did in training without an environment. :func:`evidence_of` asks the registered
plug-ins in turn and falls back to :class:`GenericEvidence` (the observation itself, or a fixed projection of it:
the generic transition mixture, no counts). The package's own plug-ins, the reserve's
(:mod:`sb3_emmarl.common.latent.reserve_evidence`) and ZonePatrol's
(:mod:`sb3_emmarl.common.latent.zone_evidence`), are registered
when ``sb3_emmarl`` is imported; ``docs/em.md`` ("Your own evidence") shows how to write one.
"""

from __future__ import annotations

import importlib
from abc import ABC, abstractmethod
from typing import Any, ClassVar, Protocol, TypeVar

import numpy as np
from stable_baselines3.common.vec_env import VecEnv

from sb3_emmarl.common.latent.features import generic_features


class CountEvidence(Protocol):
    """Counts of an environment's readings by bin, with each bin's exposure: the latent model's optional Poisson term.

    Under component ``k`` a bin's count of channel ``c`` is Poisson with mean ``exposure * rate[k, c, bin]``,
    independently over bins and steps; the E-step fits the rates in closed form
    (:func:`~sb3_emmarl.common.latent.counts.count_rates`), the beliefs add each step's log-likelihood times
    :attr:`weight`.
    """

    @property
    def n_channels(self) -> int:
        """Channels counted (``C``)."""
        ...

    @property
    def n_bins(self) -> int:
        """Bins per channel (``B``)."""
        ...

    @property
    def n_rings(self) -> int:
        """The inner factor of the bins (``B = blocks * n_rings``, block-major), for factored rates
        (``count_factors``); 1 when the bins have no such structure."""
        ...

    @property
    def weight(self) -> float:
        """The factor on the count log-likelihood in the beliefs and the E-step's responsibilities
        (``1 / temperature``: below 1 when one reading is counted at several steps)."""
        ...

    def grouped(self, observations: np.ndarray, groups: np.ndarray, n_groups: int | None = None,
                out: np.ndarray | None = None) -> np.ndarray:
        """The exposures and counts of the observations ``(n, d)`` summed by group ``(n,)`` (-1: a row to skip):
        ``(G, 1 + C, B)``, exposures first, added to ``out`` when given (the E-step's statistics)."""
        ...

    def log_likelihood(self, observations: np.ndarray, table: np.ndarray) -> np.ndarray:
        """``(n, K)``: each observation's exposures and counts times ``table`` ``(1 + C, B, K)`` (minus the rates, then
        each channel's log-rates), summed over channels and bins (the beliefs' term of one step)."""
        ...


class LatentEvidence(ABC):
    """An environment's evidence for the latent model: its features, optionally its counts, and how to rebuild them.

    A subclass sets :attr:`kind`, implements :meth:`from_env` and :meth:`features`, sets :attr:`feature_dim` (and
    :attr:`counts` and :attr:`readings`, if it has any) in ``__init__``, and is registered with
    :func:`register_evidence`.

    :param spec: plain values (JSON): ``kind``, ``obs_dim`` and what the plug-in needs to rebuild itself
    """

    #: the name saved in :attr:`spec` (``evidence_spec["kind"]`` of a saved model)
    kind: ClassVar[str]
    #: ``d_x``, the size of :meth:`features`' rows
    feature_dim: int
    #: the count evidence, or None (the transition mixture alone)
    counts: CountEvidence | None = None
    #: the indices of the features that are readings (read afresh each step, independent given the mode: the latent
    #: model gives each a Gaussian whose mean depends on the component alone; see
    #: :class:`~sb3_emmarl.common.latent.layout.LatentLayout`); empty: every feature is a transition's
    readings: tuple[int, ...] = ()

    def __init__(self, spec: dict[str, Any]) -> None:
        if spec.get("kind") != self.kind:
            raise ValueError(f"{type(self).__name__} needs a specification of kind {self.kind!r}, got {spec.get('kind')!r}")
        self.spec = spec
        self.obs_dim = int(spec["obs_dim"])

    @classmethod
    @abstractmethod
    def from_env(cls, venv: VecEnv) -> LatentEvidence | None:
        """The plug-in of ``venv``'s environment, or None when it is not one this plug-in reads (read what it needs
        with :func:`env_attribute`)."""

    @abstractmethod
    def features(self, observations: np.ndarray) -> np.ndarray:
        """Compact features ``(n, feature_dim)`` float32 of flat observations ``(n, obs_dim)``."""


Evidence = TypeVar("Evidence", bound=type[LatentEvidence])


class GenericEvidence(LatentEvidence):
    """The default: the observation itself when small, else a fixed random projection of it
    (:func:`~sb3_emmarl.common.latent.features.generic_features`); no counts."""

    kind = "generic"

    def __init__(self, spec: dict[str, Any]) -> None:
        super().__init__(spec)
        self._fn, self.feature_dim = generic_features(self.obs_dim)

    @classmethod
    def from_env(cls, venv: VecEnv) -> GenericEvidence:
        return cls({"kind": cls.kind, "obs_dim": observation_size(venv)})

    def features(self, observations: np.ndarray) -> np.ndarray:
        return self._fn(observations)


#: The registered plug-ins by kind, in the order :func:`evidence_of` asks them (the default last, not listed).
PLUGINS: dict[str, type[LatentEvidence]] = {}


def register_evidence(plugin: Evidence) -> Evidence:
    """Register a :class:`LatentEvidence` subclass (a class decorator): :func:`evidence_of` asks it, after those
    registered before, and :func:`evidence_from_spec` rebuilds its saved specifications. Import its module before
    loading a model saved with it."""
    if not (isinstance(plugin, type) and issubclass(plugin, LatentEvidence)) or not isinstance(
            getattr(plugin, "kind", None), str):
        raise TypeError(f"register_evidence takes a LatentEvidence subclass with a kind, got {plugin!r}")
    known = PLUGINS.get(plugin.kind, GenericEvidence if plugin.kind == GenericEvidence.kind else None)
    if known is not None and known.__qualname__ != plugin.__qualname__:
        raise ValueError(f"the evidence kind {plugin.kind!r} is {known.__module__}.{known.__qualname__}'s already")
    PLUGINS[plugin.kind] = plugin
    return plugin


def observation_size(venv: VecEnv) -> int:
    """The size of ``venv``'s flat observations."""
    assert venv.observation_space.shape is not None  # (a Box)
    return int(np.prod(venv.observation_space.shape))


def env_attribute(venv: VecEnv, name: str) -> Any:
    """The attribute ``name`` of ``venv``'s first environment, or None when it has none (what :meth:`from_env
    <LatentEvidence.from_env>` reads to recognise an environment)."""
    try:
        return venv.get_attr(name, indices=[0])[0]
    except (AttributeError, NotImplementedError):
        return None


#: The package's own plug-ins (``module:class``), asked before any other: registered on first use (their modules
#: import this one).
BUILTIN_PLUGINS = ("sb3_emmarl.common.latent.reserve_evidence:ReserveEvidence",
                   "sb3_emmarl.common.latent.zone_evidence:ZoneEvidence")


def registered_plugins() -> dict[str, type[LatentEvidence]]:
    """:data:`PLUGINS`, the package's own (:data:`BUILTIN_PLUGINS`) first, then the others in the order they were
    registered."""
    builtins = []
    for target in BUILTIN_PLUGINS:
        module, name = target.split(":")
        builtins.append(register_evidence(getattr(importlib.import_module(module), name)))
    ordered = {plugin.kind: plugin for plugin in builtins}
    ordered.update((kind, plugin) for kind, plugin in PLUGINS.items() if kind not in ordered)
    if list(ordered) != list(PLUGINS):
        PLUGINS.clear()
        PLUGINS.update(ordered)
    return PLUGINS


def evidence_of(venv: VecEnv) -> LatentEvidence:
    """The evidence of ``venv``'s environment: the first registered plug-in that reads it (the package's own first),
    else :class:`GenericEvidence`."""
    for plugin in registered_plugins().values():
        evidence = plugin.from_env(venv)
        if evidence is not None:
            return evidence
    return GenericEvidence.from_env(venv)


def evidence_from_spec(spec: dict[str, Any]) -> LatentEvidence:
    """The plug-in a specification (:attr:`LatentEvidence.spec`, a saved model's ``evidence_spec``) was made by."""
    plugins: dict[str, type[LatentEvidence]] = {**registered_plugins(), GenericEvidence.kind: GenericEvidence}
    kind = spec.get("kind")
    if kind not in plugins:
        *others, last = [repr(name) for name in plugins]
        allowed = f"{', '.join(others)} or {last}" if others else last
        raise ValueError(f"feature specification kind must be {allowed}, got {kind!r} (a plug-in's kind is known once "
                         "its module is imported)")
    return plugins[kind](spec)

