"""The BIMCaP paper's published numbers on ConSLAM (Tables 1 and 2), shown beside bimcap's own.

They are for comparing *relative* improvements: the paper's data (a real construction site, a
VLP-16 and a real SLAM-like drift) is not the synthetic world.
"""

from __future__ import annotations

#: Table 1 (Exp. 1): rows of (method, terms, MME, MPV, NND [m], ATE_pos [m], ATE_rot [deg]).
TABLE1: tuple[tuple[str, str, float, float, float, float, float], ...] = (
    ("GT poses", "-", 0.761, 0.040, 0.0, 0.0, 0.0),
    ("Exp. 1 (initial)", "-", 1.027, 0.059, 0.557, 1.391, 9.99),
    ("FACaP", "G+F+W", 0.979, 0.054, 0.503, 1.321, 15.40),
    ("FACaP", "G", 1.013, 0.058, 0.566, 1.385, 8.84),
    ("FACaP", "F", 0.966, 0.053, 0.503, 1.358, 16.50),
    ("FACaP", "W", 1.031, 0.059, 0.545, 1.378, 9.82),
    ("BIMCaP", "G+F+W+Co+Ce", 0.956, 0.052, 0.460, 1.281, 11.84),
    ("BIMCaP", "G+F+W+Ce", 0.959, 0.052, 0.456, 1.281, 11.81),
    ("BIMCaP", "G+F+W", 0.975, 0.053, 0.505, 1.311, 12.58),
    ("BIMCaP", "F", 0.966, 0.054, 0.519, 1.351, 13.63),
    ("BIMCaP", "W+Co", 1.034, 0.059, 0.549, 1.378, 9.75),
    ("BIMCaP", "Ce", 0.982, 0.054, 0.480, 1.387, 12.71),
)

#: Table 2 (Exp. 2 and 3): rows of (experiment, method, ATE_pos [cm], ATE_rot, yaw, pitch,
#: roll [deg]).
TABLE2: tuple[tuple[str, str, float, float, float, float, float], ...] = (
    ("exp2", "initial", 30.3, 8.82, 4.31, 4.31, 0.29),
    ("exp2", "FACaP", 30.2, 7.70, 3.79, 3.79, 0.21),
    ("exp2", "BIMCaP", 30.4, 5.61, 2.73, 2.75, 0.23),
    ("exp3", "initial", 0.0, 9.60, 4.70, 4.72, 0.29),
    ("exp3", "FACaP", 6.2, 7.92, 3.91, 3.90, 0.19),
    ("exp3", "BIMCaP", 7.2, 6.04, 2.96, 2.96, 0.22),
)


def table1_row(method: str, terms: str) -> tuple[float, float, float, float, float] | None:
    """The paper's Table 1 numbers for ``method`` ('FACaP'/'BIMCaP') and ``terms`` ('G+F+W')."""
    for m, t, *vals in TABLE1:
        if m.lower() == method.lower() and t == terms:
            return tuple(vals)  # type: ignore[return-value]
    return None


def table2_row(experiment: str, method: str) -> tuple[float, float, float, float, float] | None:
    """The paper's Table 2 numbers for ``experiment`` ('exp2'/'exp3') and ``method``."""
    for e, m, *vals in TABLE2:
        if e == experiment and m.lower() == method.lower():
            return tuple(vals)  # type: ignore[return-value]
    return None
