import os

# Pygame must never need a display in the test suite (CI has none).
os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
os.environ.setdefault("SDL_AUDIODRIVER", "dummy")
# The suite runs in 2 workers on 2 cores: torch's small networks slow down several times when each worker's threads
# compete for the other core (measured: 561 s for the suite with torch's default threads, 130 s with one).
os.environ.setdefault("OMP_NUM_THREADS", "1")

import torch  # after the thread setting

torch.set_num_threads(1)
