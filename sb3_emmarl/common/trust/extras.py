"""Optional dependencies of ``sb3_emmarl``: :func:`requires` turns a missing extra's module into one line naming the
extra to install (``the zoo needs rl_zoo3: pip install 'sb3-emmarl[zoo]'``).

Defined once for the distribution in :mod:`wildlife_reserve.utils.extras` (the lower layer, which cannot import this
package) and re-exported here.
"""

from wildlife_reserve.utils.extras import DISTRIBUTION, MissingExtra, requires

__all__ = ["DISTRIBUTION", "MissingExtra", "requires"]
