"""Terrain, risk hotspots and region presets of the wildlife reserve.

The regions are stylised presets (terrain proportions and hotspot counts), not maps of real
places. A terrain is an integer array of shape ``(height, width)`` with values
:data:`OPEN`, :data:`FOREST` and :data:`MOUNTAIN`; the risk map is a float array in [0, 1].
Everything here is vectorised over cells (no Python loop over cells).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage

OPEN, FOREST, MOUNTAIN = 0, 1, 2
TERRAIN_NAMES = ("open", "forest", "mountain")
#: Share of the visual signal lost to each terrain type (what the occlusion channel shows).
VISUAL_OCCLUSION = np.array([0.0, 0.6, 0.8], dtype=np.float32)
#: Share of the thermal signal lost to each terrain type (canopy hides less heat than rock).
THERMAL_OCCLUSION = np.array([0.0, 0.3, 0.7], dtype=np.float32)
#: Cells with a risk at or above this value are "high-risk" (coverage efficiency counts them).
HIGH_RISK_THRESHOLD = 0.5
#: Risk below this is 0. The tails of the hotspots' Gaussian bumps would otherwise reach float32's subnormal
#: range (below 1.2e-38) in the observation's risk channel, where every matrix product of a network reading
#: it runs at about two thirds of its speed on x86 CPUs.
RISK_FLOOR = 1e-6


@dataclass(frozen=True)
class RegionPreset:
    """A stylised reserve: terrain proportions and hotspot counts.

    :param forest: share of cells that are forest
    :param mountain: share of cells that are mountain
    :param n_dens: leopard dens (risk 1.0 at the centre)
    :param n_waterholes: water holes (risk 0.8)
    :param n_roads: roads entering from the edge (risk 0.6 along them)
    :param smoothness: spatial scale of the terrain patches, as a fraction of the grid side
    """

    forest: float
    mountain: float
    n_dens: int
    n_waterholes: int
    n_roads: int
    smoothness: float = 0.08


REGIONS: dict[str, RegionPreset] = {
    # Mixed woodland and open valleys, the default reserve.
    "mixed": RegionPreset(forest=0.35, mountain=0.15, n_dens=4, n_waterholes=3, n_roads=2),
    # Dense Hyrcanian-style forest: heavy occlusion everywhere.
    "forest": RegionPreset(forest=0.70, mountain=0.10, n_dens=4, n_waterholes=2, n_roads=1),
    # Rugged mountain steppe: rock occludes, few roads.
    "mountain": RegionPreset(forest=0.15, mountain=0.50, n_dens=3, n_waterholes=2, n_roads=1, smoothness=0.12),
    # Open plains: little cover, many water holes and roads.
    "steppe": RegionPreset(forest=0.08, mountain=0.05, n_dens=3, n_waterholes=5, n_roads=3, smoothness=0.05),
}


def generate_terrain(rng: np.random.Generator, shape: tuple[int, int], preset: RegionPreset) -> np.ndarray:
    """Draw a terrain from smoothed noise, thresholded to the preset's proportions.

    :param rng: random generator
    :param shape: ``(height, width)``
    :param preset: the region preset
    :return: int8 array of terrain types
    """
    height, width = shape
    sigma = max(1.0, preset.smoothness * max(height, width))
    elevation = ndimage.gaussian_filter(rng.standard_normal(shape), sigma=sigma, mode="wrap")
    vegetation = ndimage.gaussian_filter(rng.standard_normal(shape), sigma=sigma, mode="wrap")
    terrain = np.full(shape, OPEN, dtype=np.int8)
    # Mountains take the highest ground; forest the greenest of the rest.
    mountain = elevation >= np.quantile(elevation, 1.0 - preset.mountain) if preset.mountain > 0 else np.zeros(shape, bool)
    terrain[mountain] = MOUNTAIN
    rest = ~mountain
    n_forest = round(preset.forest * height * width)
    if n_forest > 0 and rest.any():
        order = np.argsort(-vegetation[rest], kind="stable")[:n_forest]
        idx = np.flatnonzero(rest)[order]
        terrain.flat[idx] = FOREST
    return terrain


def _sample_cells(rng: np.random.Generator, weights: np.ndarray, count: int, min_dist: float) -> np.ndarray:
    """Sample ``count`` cells with probability proportional to ``weights``, spaced when possible."""
    width = weights.shape[1]
    flat = weights.ravel().astype(np.float64)
    chosen: list[np.ndarray] = []
    rows, cols = np.divmod(np.arange(flat.size), width)
    for _ in range(count):
        p = flat / flat.sum()
        cell = rng.choice(flat.size, p=p)
        chosen.append(np.array([rows[cell], cols[cell]]))
        near = (np.abs(rows - rows[cell]) < min_dist) & (np.abs(cols - cols[cell]) < min_dist)
        spaced = np.where(near, 0.0, flat)
        if spaced.sum() > 0:
            flat = spaced
        elif flat.sum() > flat[cell]:
            flat[cell] = 0.0
    return np.array(chosen, dtype=np.int64).reshape(count, 2)


@dataclass
class Hotspots:
    """Where the risk comes from: leopard dens, water holes and road cells, and the edge cells where the roads enter
    the reserve (``(k, 2)`` int arrays)."""

    dens: np.ndarray
    waterholes: np.ndarray
    roads: np.ndarray
    road_entries: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), dtype=np.int64))


def generate_hotspots(rng: np.random.Generator, terrain: np.ndarray, preset: RegionPreset) -> Hotspots:
    """Place dens (in cover, away from the edge), water holes (in the open) and roads (from an edge inward).

    :param rng: random generator
    :param terrain: terrain array
    :param preset: the region preset (hotspot counts)
    """
    height, width = terrain.shape
    rows, cols = np.indices(terrain.shape)
    edge_dist = np.minimum.reduce([rows, cols, height - 1 - rows, width - 1 - cols]).astype(np.float64)
    inner = np.clip(edge_dist / max(1.0, 0.15 * min(height, width)), 0.0, 1.0) + 1e-3
    spacing = max(2.0, 0.2 * min(height, width))
    den_weight = inner * np.where(terrain == OPEN, 0.2, 1.0)
    dens = _sample_cells(rng, den_weight, max(1, preset.n_dens), spacing)
    water_weight = inner * np.where(terrain == OPEN, 1.0, 0.1)
    waterholes = _sample_cells(rng, water_weight, preset.n_waterholes, spacing / 2)
    road_cells, entries = [], []
    for _ in range(preset.n_roads):
        side = rng.integers(4)
        along = width if side < 2 else height
        start = edge_points(np.array(side), np.array(rng.integers(along) / max(along - 1, 1)), (height, width))
        end = np.array([rng.integers(height // 4, max(height // 4 + 1, 3 * height // 4)),
                        rng.integers(width // 4, max(width // 4 + 1, 3 * width // 4))])
        n = int(np.abs(end - start).max()) + 1
        line = np.rint(np.linspace(start, end, n)).astype(np.int64)
        road_cells.append(line)
        entries.append(line[0])
    roads = np.concatenate(road_cells) if road_cells else np.zeros((0, 2), dtype=np.int64)
    road_entries = np.array(entries, dtype=np.int64).reshape(-1, 2)
    return Hotspots(dens=dens, waterholes=waterholes, roads=roads, road_entries=road_entries)


def edge_points(side: np.ndarray, frac: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """Cells on the border: side 0 north, 1 south, 2 west, 3 east; ``frac`` in [0, 1] along it."""
    height, width = shape
    along_row = np.rint(frac * (height - 1)).astype(np.int64)
    along_col = np.rint(frac * (width - 1)).astype(np.int64)
    rows = np.choose(side, [np.zeros_like(along_col), np.full_like(along_col, height - 1), along_row, along_row])
    cols = np.choose(side, [along_col, along_col, np.zeros_like(along_row), np.full_like(along_row, width - 1)])
    return np.stack([rows, cols], axis=-1)


def nearest_edge(cells: np.ndarray, shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """For each cell, the nearest side and the fraction along it (the cell's projection on the border)."""
    height, width = shape
    dists = np.stack([cells[:, 0], height - 1 - cells[:, 0], cells[:, 1], width - 1 - cells[:, 1]], axis=-1)
    side = dists.argmin(axis=-1)
    frac = np.where(side < 2, cells[:, 1] / max(width - 1, 1), cells[:, 0] / max(height - 1, 1))
    return side, frac


def risk_map(shape: tuple[int, int], hotspots: Hotspots) -> np.ndarray:
    """Risk in [0, 1]: the maximum of Gaussian bumps at dens (1.0) and water holes (0.8), and 0.6 along roads.

    :param shape: ``(height, width)``
    :param hotspots: the hotspots
    :return: float32 risk array
    """
    height, width = shape
    scale = max(1.5, 0.04 * min(height, width))
    rows, cols = np.indices(shape, dtype=np.float64)
    risk = np.zeros(shape)
    for centres, peak in ((hotspots.dens, 1.0), (hotspots.waterholes, 0.8)):
        for r, c in centres:
            bump = peak * np.exp(-((rows - r) ** 2 + (cols - c) ** 2) / (2 * scale**2))
            np.maximum(risk, bump, out=risk)
    if len(hotspots.roads):
        on_road = np.zeros(shape, dtype=bool)
        on_road[hotspots.roads[:, 0], hotspots.roads[:, 1]] = True
        near_road = ndimage.binary_dilation(on_road, iterations=1)
        np.maximum(risk, np.where(near_road, 0.6, 0.0), out=risk)
    return as_risk(risk)


def sectors(cells: np.ndarray, n: int) -> np.ndarray:
    """Split the True cells of ``cells`` into ``n`` sectors of equal count (up to one cell) by their angle around the
    grid's centre: the cells ranked by ``arctan2(row - height / 2, col - width / 2)`` (ties in row-major order), the
    first ``count / n`` of them sector 0, and so on.

    :param cells: bool array ``(height, width)``
    :param n: number of sectors, >= 1
    :return: int array ``(height, width)``: each True cell's sector in ``[0, n)``, -1 elsewhere
    """
    rows, cols = np.nonzero(cells)
    angle = np.arctan2(rows - cells.shape[0] / 2, cols - cells.shape[1] / 2)
    rank = np.empty(len(rows), dtype=np.int64)
    rank[np.argsort(angle, kind="stable")] = np.arange(len(rows))
    out = np.full(cells.shape, -1, dtype=np.int64)
    out[rows, cols] = rank * n // max(len(rows), 1)
    return out


def strategy_zones(shape: tuple[int, int], n: int) -> np.ndarray:
    """The centres of ``n`` strategy zones (``strategy_zones``: each poacher strategy strikes its own): the centres of
    the map's quarters, row-major (north-west, north-east, south-west, south-east), cycled when ``n > 4``. On a 100 x 100
    map they lie 50 cells apart (Chebyshev), 25 from the two nearest sides.

    :param shape: ``(height, width)``
    :param n: number of zones, >= 1
    :return: int array ``(n, 2)``
    """
    height, width = shape
    quarters = np.array([[height // 4, width // 4], [height // 4, (3 * width) // 4],
                         [(3 * height) // 4, width // 4], [(3 * height) // 4, (3 * width) // 4]], dtype=np.int64)
    return quarters[np.arange(n) % len(quarters)]


def as_risk(values: np.ndarray) -> np.ndarray:
    """A risk map as the reserve keeps it: float32, values below :data:`RISK_FLOOR` set to 0."""
    risk = np.asarray(values, dtype=np.float32).copy()
    risk[risk < RISK_FLOOR] = 0.0
    return risk


def dens_from_risk(rng: np.random.Generator, risk: np.ndarray, count: int) -> np.ndarray:
    """Pick leopard dens among the riskiest cells of a user-supplied risk map."""
    spacing = max(2.0, 0.2 * min(risk.shape))
    return _sample_cells(rng, risk.astype(np.float64) ** 4 + 1e-9, max(1, count), spacing)
