"""A tiny two-storey world for the deviation tests: the design, its as-built (walls shifted by up
to 5.4 cm, except the datum walls ext-south and ext-west, kept at design; the corridor column
missing) and 12 frames walked on the ground floor (the upper storey is never seen)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

#: as_built seed: S0's corridor column missing, S0/wall/corr-north +3.7 cm, corr-south -4.2 cm.
AS_BUILT_SEED = 20
#: Walls the as-built keeps exactly at design on every storey (the datum of the datum tests);
#: the other elements' shifts and the missing ones are those without it.
DATUM = ("ext-south", "ext-west")


def make_deviation_world(root: Path, frames: int = 12) -> dict[str, Path]:
    """Write ``design.ifc``, ``built.ifc`` (+ ``built.truth.json``) and the sequence ``seq``."""
    from bimcap.sim.building import BuildingSpec, as_built, generate_building
    from bimcap.sim.simulator import SimulatorConfig, simulate

    spec = replace(BuildingSpec.tiny(), storeys=2)
    design = generate_building(spec, seed=0, ifc_path=root / "design.ifc")
    as_built(design, seed=AS_BUILT_SEED, missing_fraction=0.3, datum=DATUM,
             ifc_path=root / "built.ifc")
    simulate(root / "design.ifc", root / "seq", SimulatorConfig.small(frames=frames, fps=1.0),
             seed=2, as_built_ifc=root / "built.ifc")
    return {"design": root / "design.ifc", "built": root / "built.ifc",
            "truth": root / "built.truth.json", "seq": root / "seq"}
