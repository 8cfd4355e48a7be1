import os
from pathlib import Path

# Reuse compiled Warp kernels across runs (the Makefile sets the same folder).
os.environ.setdefault("WARP_CACHE_PATH", str(Path(__file__).resolve().parents[1] / ".cache" / "warp"))
