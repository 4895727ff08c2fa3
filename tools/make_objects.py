"""Write the course's Bezier-patch objects to src/diffnurbs/data/NAME.bpt."""

from pathlib import Path

import jax

from diffnurbs import io
from diffnurbs._objects import PROFILES, design_object

DATA = Path(__file__).resolve().parents[1] / "src" / "diffnurbs" / "data"

if __name__ == "__main__":
    jax.config.update("jax_enable_x64", True)
    for name in PROFILES:
        io.write_bpt(DATA / f"{name}.bpt", design_object(name))
        print(f"wrote {DATA / name}.bpt")
