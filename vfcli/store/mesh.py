"""The typed reader of /mesh: the fold mesh and the material it was built for."""
from __future__ import annotations

import json
from dataclasses import dataclass

from vfcli.model.mesh import FoldMesh
from vfcli.store import layout
from vfcli.store.reader import StoreReader


@dataclass(frozen=True)
class StoredMesh:
    """What /mesh holds, as one value.

    Attributes
    ----------
    mesh : FoldMesh
        The tetrahedral mesh of both folds (mm).
    youngs_modulus_pa : float
        Young's modulus E the mesh stage recorded, Pa.
    poisson_ratio : float
        Poisson's ratio nu (1).
    density_kg_m3 : float
        Density, kg/m^3.
    length_mm : float
        Anterior-posterior length L of the folds (mesh.length_mm of the stage's config), mm.
    """

    mesh: FoldMesh
    youngs_modulus_pa: float
    poisson_ratio: float
    density_kg_m3: float
    length_mm: float


def read_mesh(reader: StoreReader) -> FoldMesh:
    """The FoldMesh stored in /mesh (:class:`vfcli.errors.MissingStageError` when absent)."""
    return FoldMesh(**{k: reader.read("mesh", k) for k in layout.stage("mesh").datasets})


def read_stored_mesh(reader: StoreReader) -> StoredMesh:
    """/mesh with its material and length: the values hashed into the stage, not the live config."""
    attrs = reader.attrs("mesh")
    cfg = json.loads(str(attrs["config_json"]))
    return StoredMesh(read_mesh(reader), float(attrs["youngs_modulus_pa"]), float(attrs["poisson_ratio"]),
                      float(attrs["density_kg_m3"]), float(cfg["length_mm"]))
