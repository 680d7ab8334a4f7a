"""DEM runs (LAMMPS / LIGGGHTS dumps) as a data source: the same concentration maps and
velocity profiles as footage gives, from ``dump custom`` files and a small config
(docs/formats.md, "DEM particle dumps").

    >>> run = load_run("runs/ratio2", config="examples/dem/dem.json")   # doctest: +SKIP
    >>> run.to_map("wall").save("ratio2-wall.npz")                       # doctest: +SKIP
    >>> run.velocity_profile().delta_over_H                              # doctest: +SKIP
"""

from granseg.dem.config import DemConfig, Material, load_config
from granseg.dem.dump import Snapshot, read_dumps
from granseg.dem.run import VIEWS, DemRun, load_run

__all__ = ["DemConfig", "DemRun", "Material", "Snapshot", "VIEWS", "load_config", "load_run", "read_dumps"]
