"""Pygame drawing of the reserve, as PettingZoo's own environments render.

Terrain and risk are drawn once per map onto a background surface; each frame adds the signs of
poacher activity (brown, orange once the team found them), the UAVs (with their sensing footprints
and the messages delivered this step), leopards, poachers, decoys, this step's readings and the jammer.
"""

from __future__ import annotations

import os
from typing import Any

import numpy as np

from wildlife_reserve.reserve.kernels.constants import POACHER_ACTIVE, POACHER_CAUGHT
from wildlife_reserve.reserve.view import ReserveView
from wildlife_reserve.utils.extras import requires

TERRAIN_COLOURS = np.array([[196, 214, 150], [52, 110, 60], [128, 118, 108]], dtype=np.float64)
RISK_COLOUR = np.array([230, 120, 40], dtype=np.float64)
UAV_COLOUR, GROUNDED_COLOUR = (40, 90, 230), (90, 90, 120)
LEOPARD_COLOUR, POACHER_COLOUR, CAUGHT_COLOUR = (250, 200, 30), (220, 30, 30), (255, 255, 255)
READING_COLOUR, LINK_COLOUR, DECOY_COLOUR = (255, 0, 255), (120, 200, 255), (160, 0, 160)
SIGN_COLOUR, FOUND_SIGN_COLOUR = (110, 60, 20), (255, 140, 0)
#: Largest side of the picture in pixels; each cell gets at least 2 pixels.
TARGET_PIXELS = 600


class ReserveRenderer:
    """Draws a :class:`~wildlife_reserve.reserve.reserve.ReserveParallelEnv` (any
    :class:`~wildlife_reserve.reserve.view.ReserveView`).

    :param env: the environment to draw
    :param mode: ``"rgb_array"`` (returns frames) or ``"human"`` (a pygame window)
    :param fps: frames per second of the window (``"human"``)
    """

    def __init__(self, env: ReserveView, mode: str, fps: int) -> None:
        self.fps = fps
        if mode == "rgb_array":
            os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
        with requires("pygame", "render", "drawing the reserve"):
            import pygame

        self.pygame = pygame
        self.env = env
        self.mode = mode
        self.cell = max(2, TARGET_PIXELS // max(env.height, env.width))
        self.size = (env.width * self.cell, env.height * self.cell)
        self.window: Any = None
        self.clock: Any = None
        self._background: Any = None
        self._background_key: tuple | None = None
        pygame.init()
        if mode == "human":
            pygame.display.init()
            self.window = pygame.display.set_mode(self.size)
            pygame.display.set_caption("Wildlife reserve")
            self.clock = pygame.time.Clock()
        self.canvas = pygame.Surface(self.size)

    def _draw_background(self) -> None:
        env = self.env
        key = (id(env.terrain), id(env.risk))
        if self._background is not None and self._background_key == key:
            return
        base = TERRAIN_COLOURS[env.terrain]
        shade = 0.55 * env.risk[..., None]
        rgb = (1 - shade) * base + shade * RISK_COLOUR
        rgb = np.repeat(np.repeat(rgb, self.cell, axis=0), self.cell, axis=1).astype(np.uint8)
        self._background = self.pygame.surfarray.make_surface(rgb.transpose(1, 0, 2))
        self._background_key = key

    def _centre(self, rc: np.ndarray) -> tuple[int, int]:
        return int((rc[1] + 0.5) * self.cell), int((rc[0] + 0.5) * self.cell)

    def draw(self) -> np.ndarray | None:
        """Draw one frame; return it as ``(height, width, 3)`` uint8 in ``"rgb_array"`` mode."""
        pg, env, cell = self.pygame, self.env, self.cell
        self._draw_background()
        canvas = self.canvas
        canvas.blit(self._background, (0, 0))
        reach = env.reach * cell
        cells = np.floor(env.uav_pos).astype(np.int64)
        for s, r in zip(*np.nonzero(env.comm_links)):
            pg.draw.line(canvas, LINK_COLOUR, self._centre(cells[s]), self._centre(cells[r]), 1)
        for i, rc in enumerate(cells):
            x, y = self._centre(rc)
            colour = GROUNDED_COLOUR if env.grounded[i] else UAV_COLOUR
            pg.draw.rect(canvas, colour, (x - reach - cell // 2, y - reach - cell // 2, 2 * reach + cell, 2 * reach + cell), 1)
            pg.draw.circle(canvas, colour, (x, y), max(2, cell))
        for pos, alive in zip(env.leopard_pos, env.leopard_alive):
            pg.draw.circle(canvas, LEOPARD_COLOUR if alive else (0, 0, 0), self._centre(pos), max(2, cell), 0 if alive else 1)
        live = env.signs.live(env.t)
        found = np.asarray(env.team.known_signs.any(axis=0))
        for index in live:
            colour = FOUND_SIGN_COLOUR if index < len(found) and found[index] else SIGN_COLOUR
            x, y = self._centre(env.signs.pos[index])
            pg.draw.rect(canvas, colour, (x - cell // 2, y - cell // 2, max(2, cell), max(2, cell)))
        for pos in env.decoy_pos:
            pg.draw.circle(canvas, DECOY_COLOUR, self._centre(pos), max(2, cell // 2 + 1), 1)
        for pos, status in zip(env.poacher_pos, env.poacher_status):
            if status in (POACHER_ACTIVE, POACHER_CAUGHT):
                colour = POACHER_COLOUR if status == POACHER_ACTIVE else CAUGHT_COLOUR
                x, y = self._centre(pos)
                half = max(2, cell)
                pg.draw.line(canvas, colour, (x - half, y - half), (x + half, y + half), 2)
                pg.draw.line(canvas, colour, (x - half, y + half), (x + half, y - half), 2)
        for _, row, col in env.detections:
            x, y = self._centre(np.array([row, col]))
            pg.draw.rect(canvas, READING_COLOUR, (x - cell, y - cell, 2 * cell, 2 * cell), 1)
        if env.jammer_pos is not None:
            pg.draw.circle(canvas, DECOY_COLOUR, self._centre(env.jammer_pos), int(env.config.jam_radius * cell), 1)
        if self.mode == "human":
            self.pygame.event.pump()
            self.window.blit(canvas, (0, 0))
            self.pygame.display.update()
            self.clock.tick(self.fps)
            return None
        return np.ascontiguousarray(np.transpose(pg.surfarray.pixels3d(canvas), (1, 0, 2)))

    def close(self) -> None:
        """Close the window (if any)."""
        if self.window is not None:
            self.pygame.display.quit()
            self.window = None
        self.pygame.quit()
