"""Optional dependencies: an import that needs an extra of the ``sb3-emmarl`` distribution (``[render]``, ``[zoo]``,
``[plots]``, ``[ray]``) fails with one line naming the extra to install.

Both packages of the distribution use :func:`requires` (``sb3_emmarl.common.trust.extras`` re-exports it), as in::

    with requires("pygame", "render", "drawing the reserve"):
        import pygame
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

#: The distribution whose extras the messages name.
DISTRIBUTION = "sb3-emmarl"


class MissingExtra(ModuleNotFoundError):
    """A module of an extra of the distribution is not installed; the message is one line with the ``pip install``
    command that adds it.

    :param module: the missing module (its top-level name)
    :param extra: the extra that installs it
    :param purpose: what needs it, e.g. ``"the zoo"``
    """

    def __init__(self, module: str, extra: str, purpose: str) -> None:
        super().__init__(f"{purpose} needs {module}: pip install '{DISTRIBUTION}[{extra}]'", name=module)
        self.extra = extra


@contextmanager
def requires(module: str, extra: str, purpose: str) -> Iterator[None]:
    """Turn the absence of ``module`` in the imports of the ``with`` block into :class:`MissingExtra`.

    Only the module itself missing is turned (``ModuleNotFoundError`` naming it or one of its submodules); an error
    inside an installed module, or another missing module, passes unchanged, so that a broken install is not reported
    as a missing extra.

    :param module: the top-level module the extra provides, e.g. ``"rl_zoo3"``
    :param extra: the extra of the distribution that installs it, e.g. ``"zoo"``
    :param purpose: what needs it, for the message, e.g. ``"the zoo"``
    :raise MissingExtra: when ``module`` is not installed
    """
    try:
        yield
    except ModuleNotFoundError as error:
        if error.name is None or error.name.split(".")[0] != module:
            raise
        raise MissingExtra(module, extra, purpose) from None
