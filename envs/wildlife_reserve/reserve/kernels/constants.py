"""Names that several modules of the reserve share: observation channels, actions, poacher statuses.

Kept apart from the environment class so that rendering, scripted patrols and the centralised view
can name them without importing the whole environment.
"""

from __future__ import annotations

import numpy as np

#: Channels of the egocentric observation window, in order.
N_CHANNELS = 7
CH_OCCLUSION, CH_RISK, CH_STALENESS, CH_POACHER, CH_LEOPARD, CH_UAV, CH_SIGN = range(N_CHANNELS)
CHANNEL_NAMES = ("occlusion", "risk", "staleness", "poacher", "leopard", "uav", "sign")

#: Discrete actions are ``move + N_MOVES * comm``.
N_MOVES, N_COMMS = 5, 3
STAY, UP, DOWN, LEFT, RIGHT = range(N_MOVES)
COMM_NONE, COMM_BROADCAST, COMM_QUERY = range(N_COMMS)

#: A poacher waits to enter, is active in the reserve, was caught (detected), or left after poaching.
POACHER_WAITING, POACHER_ACTIVE, POACHER_CAUGHT, POACHER_GONE = range(4)

#: Timestamp of a cell nobody has seen.
NEVER = np.float32(-1.0e6)
