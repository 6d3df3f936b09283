"""Text edits that damage or move an IFC STEP file the way users' files go wrong (issue 12).

Not collected (no ``test_`` prefix). Each function takes the file's text and returns the edited
text; tests write it to ``tmp_path``. They work on the real models of ``../shared/data/ifc`` and
on the buildings ``bimcap.sim.building`` writes.
"""

from __future__ import annotations

import re

_DEF = re.compile(r"^#(\d+)\s*=\s*([A-Z0-9_]+)\((.*)\);\s*$", re.M)


def _max_id(text: str) -> int:
    return max(int(m) for m in re.findall(r"^#(\d+)\s*=", text, re.M))


def _append(text: str, lines: list[str]) -> str:
    """``lines`` inserted at the end of the DATA section."""
    at = text.index("ENDSEC;", text.index("DATA;"))
    return text[:at] + "".join(line + "\n" for line in lines) + text[at:]


def move_up(text: str, dz: float) -> str:
    """The whole model moved up by ``dz`` metres, as a georeferenced export does: every root
    placement (IfcLocalPlacement without PlacementRelTo) gets a new location point ``dz`` higher.
    Storey ``Elevation`` attributes are left as they are (they are relative to the building)."""
    next_id = _max_id(text) + 1
    new_points = []
    out = text
    axes = {m.group(1) for m in
            re.finditer(r"^#\d+\s*=\s*IFCLOCALPLACEMENT\(\s*\$\s*,\s*(#\d+)\s*\)", text, re.M)}
    for axis in sorted(axes):
        am = re.search(rf"^({re.escape(axis)}\s*=\s*IFCAXIS2PLACEMENT3D\(\s*)(#\d+)", out, re.M)
        assert am is not None, axis
        pm = re.search(rf"^{re.escape(am.group(2))}\s*=\s*IFCCARTESIANPOINT\(\(([^)]*)\)\)", out,
                       re.M)
        assert pm is not None, am.group(2)
        xyz = [float(v) for v in pm.group(1).split(",")] + [0.0] * 3
        new_points.append(f"#{next_id}=IFCCARTESIANPOINT(({xyz[0]!r},{xyz[1]!r},"
                          f"{xyz[2] + dz!r}));")
        out = out[: am.start(2)] + f"#{next_id}" + out[am.end(2):]
        next_id += 1
    assert new_points, "no root placement"
    return _append(out, new_points)


def drop_storeys(text: str) -> str:
    """Every IfcBuildingStorey turned into an IfcBuilding (10 → 12 attributes), so the model has
    no storey at all while every reference stays valid."""
    out, n = re.subn(r"IFCBUILDINGSTOREY\((.*)\);", lambda m: f"IFCBUILDING({m.group(1)},$,$);",
                     text)
    assert n > 0
    return out


def length_unit_prefix(text: str, prefix: str = "MILLI") -> str:
    """The length unit given a prefix without rescaling the coordinates."""
    out, n = re.subn(r"IFCSIUNIT\(\*\s*,\s*\.LENGTHUNIT\.\s*,\s*\$\s*,\s*\.METRE\.\)",
                     f"IFCSIUNIT(*,.LENGTHUNIT.,.{prefix}.,.METRE.)", text)
    assert n > 0
    return out


def cut(text: str, fraction: float) -> str:
    """The DATA section cut after ``fraction`` of its bytes (at a line end), with the section end
    and the trailer re-appended: passes the trailer check, loses what came after the cut."""
    data = text.index("DATA;")
    end = text.index("ENDSEC;", data)
    at = text.index("\n", data + int((end - data) * fraction)) + 1
    return text[:at] + "ENDSEC;\nEND-ISO-10303-21;\n"


def rename_class(text: str, cls: str, new: str, count: int = 1) -> str:
    """The first ``count`` instances of ``cls`` given an unknown class name ``new`` (a malformed
    line: IfcOpenShell drops the instance)."""
    done = 0

    def sub(m: re.Match[str]) -> str:
        nonlocal done
        if done >= count:
            return m.group(0)
        done += 1
        return m.group(1) + new + "("

    out = re.sub(rf"^(#\d+\s*=\s*){cls}\(", sub, text, flags=re.M)
    assert done == count, (cls, done)
    return out


def double_paren(text: str, cls: str) -> str:
    """The first instance of ``cls`` with a doubled opening parenthesis: IfcOpenShell's parser
    reads the rest of the file into that one instance (everything after it is lost)."""
    out, n = re.subn(rf"^(#\d+\s*=\s*{cls})\(", r"\1((", text, count=1, flags=re.M)
    assert n == 1
    return out
