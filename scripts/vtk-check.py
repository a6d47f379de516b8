#!/usr/bin/env python3
"""Read mpm's particle snapshots with VTK's own XML readers and check them against the run.

    vtk-check.py PVD STATE --ranks R --encoding ascii|binary|compressed

PVD is the run's `.pvd` collection (`mpm run ... --vtk DIR`), STATE its final particle state
(`--dump-state FILE`: per particle its id as u64, then position, velocity and stress
(Voigt xx yy zz yz zx xy) as f64, little-endian). Checked:

* the collection parses as XML and lists its snapshots in time order, each a `.vtu` (one
  rank) or a `.pvtu` (R ranks), each of them read by VTK (vtkXMLUnstructuredGridReader or
  vtkXMLPUnstructuredGridReader) without an error, as an unstructured grid of vertices,
  with the same particle count;
* the arrays are stored as asked (`ascii`, inline base64 `binary`, zlib `compressed`
  appended data);
* the last snapshot (over R ranks: R pieces, each also read alone by
  vtkXMLUnstructuredGridReader, their counts adding up) holds every particle of STATE:
  the point count, the field names, positions, velocities and stresses bit for bit
  (matched by position), pressure and von Mises stress from the stress to round-off,
  density positive, plastic strain non-negative, failure flags 0 or 1; a one-rank
  snapshot's TIME is its collection's time.

VTK's Python wheel has no reader of `.pvd` files (ParaView's vtkPVDReader is not in VTK):
the collection is read as XML and each file it names by VTK.

Needs the `vtk` wheel (and numpy, which it brings): scripts/bootstrap.sh installs it into
~/.cache/mpm-bench-tools/venv. Exits 0 when every check holds, 1 naming the first that does
not, 2 when VTK cannot be imported.
"""

import argparse
import os
import sys
import xml.etree.ElementTree as ET

try:
    import numpy as np
    from vtkmodules.util.numpy_support import vtk_to_numpy
    from vtkmodules.vtkCommonCore import vtkCommand
    from vtkmodules.vtkCommonDataModel import VTK_VERTEX, vtkUnstructuredGrid
    from vtkmodules.vtkIOXML import vtkXMLPUnstructuredGridReader, vtkXMLUnstructuredGridReader
except ImportError as e:
    sys.stderr.write(
        f"vtk-check: VTK's Python module cannot be imported ({e}): run scripts/bootstrap.sh, which "
        "installs the vtk wheel into ~/.cache/mpm-bench-tools/venv, and run this script with that "
        "venv's python\n"
    )
    sys.exit(2)

POINT_DATA = ["velocity", "stress", "pressure", "von_mises", "eps_p", "density", "failed"]
RECORD = np.dtype([("id", "<u8"), ("x", "<f8", 3), ("v", "<f8", 3), ("stress", "<f8", 6)])


class Failed(Exception):
    """A check that does not hold."""


def check(ok, what):
    if not ok:
        raise Failed(what)


def read(reader_class, path):
    """`path` read by VTK's `reader_class`; any error VTK reports fails the check."""
    reader = reader_class()
    errors = []
    reader.AddObserver(vtkCommand.ErrorEvent, lambda _o, _e: errors.append(True))
    reader.GetExecutive().AddObserver(vtkCommand.ErrorEvent, lambda _o, _e: errors.append(True))
    reader.SetFileName(path)
    reader.Update()
    check(not errors, f"{path}: VTK's {reader_class.__name__} reported an error")
    out = reader.GetOutputDataObject(0)
    check(isinstance(out, vtkUnstructuredGrid), f"{path}: read as {type(out).__name__}, not an unstructured grid")
    return out


def collection(pvd, ranks):
    """The collection's `(time, path)` entries, checked."""
    root = ET.parse(pvd).getroot()
    check(root.tag == "VTKFile" and root.get("type") == "Collection", f"{pvd}: not a VTK collection")
    entries = [(float(d.get("timestep")), d.get("file")) for d in root.iter("DataSet")]
    check(len(entries) >= 2, f"{pvd}: {len(entries)} snapshot(s), expected the initial one and more")
    times = [t for t, _ in entries]
    check(times == sorted(times), f"{pvd}: times out of order: {times}")
    ext = ".vtu" if ranks == 1 else ".pvtu"
    for _, f in entries:
        check(f.endswith(ext), f"{pvd}: {f} is not a {ext} file")
    base = os.path.dirname(pvd)
    return [(t, os.path.join(base, f)) for t, f in entries]


def stored_as(path, encoding, ranks):
    """The arrays of `path` (its first piece over several ranks) are stored as `encoding`."""
    if ranks > 1:
        root = ET.parse(path).getroot()
        path = os.path.join(os.path.dirname(path), root.find("PUnstructuredGrid/Piece").get("Source"))
    with open(path, "rb") as f:
        head = f.read().split(b"<AppendedData")[0].decode()
    want = {"ascii": 'format="ascii"', "binary": 'format="binary"', "compressed": 'format="appended"'}[encoding]
    field_data = ('Name="TIME"', 'Name="CYCLE"')
    arrays = [a for a in head.splitlines() if "<DataArray" in a and not any(f in a for f in field_data)]
    check(arrays and all(want in a for a in arrays), f"{path}: arrays not all stored as {encoding} ({want})")
    if encoding == "compressed":
        check('compressor="vtkZLibDataCompressor"' in head, f"{path}: compressed without naming VTK's zlib compressor")


def arrays(grid, path):
    """Point data of `grid` by name, as numpy arrays, and its points."""
    pd = grid.GetPointData()
    names = [pd.GetArrayName(i) for i in range(pd.GetNumberOfArrays())]
    check(names == POINT_DATA, f"{path}: point data {names}, expected {POINT_DATA}")
    fields = {n: vtk_to_numpy(pd.GetArray(n)) for n in names}
    check(grid.GetPoints() is not None, f"{path}: no points")
    return vtk_to_numpy(grid.GetPoints().GetData()), fields


def vertices(grid, path):
    """One VTK_VERTEX cell per point."""
    n = grid.GetNumberOfPoints()
    check(grid.GetNumberOfCells() == n, f"{path}: {grid.GetNumberOfCells()} cells for {n} points")
    types = vtk_to_numpy(grid.GetCellTypesArray()) if n else np.array([], dtype=np.uint8)
    check(np.all(types == VTK_VERTEX), f"{path}: cells other than VTK_VERTEX")


def snapshot(path, ranks):
    """One snapshot read by VTK's reader of its kind."""
    return read(vtkXMLUnstructuredGridReader if ranks == 1 else vtkXMLPUnstructuredGridReader, path)


def last_snapshot(path, ranks):
    """The last snapshot read by VTK, over ranks its pieces also one by one."""
    if ranks == 1:
        return snapshot(path, ranks)
    root = ET.parse(path).getroot()
    pieces = [p.get("Source") for p in root.iter("Piece")]
    check(len(pieces) == ranks, f"{path}: {len(pieces)} pieces for {ranks} ranks")
    pdecl = [a.get("Name") for a in root.find("PUnstructuredGrid/PPointData").iter("PDataArray")]
    check(pdecl == POINT_DATA, f"{path}: PPointData declares {pdecl}, expected {POINT_DATA}")
    counts = 0
    for p in pieces:
        piece = read(vtkXMLUnstructuredGridReader, os.path.join(os.path.dirname(path), p))
        arrays(piece, p)
        counts += piece.GetNumberOfPoints()
    grid = snapshot(path, ranks)
    check(grid.GetNumberOfPoints() == counts, f"{path}: {grid.GetNumberOfPoints()} points, its pieces {counts}")
    return grid


def by_position(x):
    """The order that sorts the rows of `x` (n x 3) by z, then y, then x."""
    return np.lexsort((x[:, 0], x[:, 1], x[:, 2]))


def against_state(grid, path, state):
    """The snapshot holds the particles of `state`."""
    x, f = arrays(grid, path)
    check(len(x) == len(state), f"{path}: {len(x)} points, the run's final state {len(state)} particles")
    mine, theirs = by_position(x), by_position(state["x"])
    x, s = x[mine], state[theirs]
    check(np.array_equal(x, s["x"]), f"{path}: positions differ from the run's final state")
    for name, key in [("velocity", "v"), ("stress", "stress")]:
        check(np.array_equal(f[name][mine], s[key]), f"{path}: {name} differs from the run's final state")
    sig = s["stress"]
    pressure = -(sig[:, 0] + sig[:, 1] + sig[:, 2]) / 3.0
    dev = sig[:, :3] + pressure[:, None]
    von_mises = np.sqrt(1.5 * ((dev**2).sum(axis=1) + 2.0 * (sig[:, 3:] ** 2).sum(axis=1)))
    scale = max(np.abs(sig).max(), 1.0)
    for name, want in [("pressure", pressure), ("von_mises", von_mises)]:
        err = np.abs(f[name][mine] - want).max(initial=0.0)
        check(err <= 1e-12 * scale, f"{path}: {name} is {err:.3e} Pa from the stress's")
    check(np.all(f["density"] > 0), f"{path}: a density not positive")
    check(np.all(f["eps_p"] >= 0), f"{path}: a negative plastic strain")
    check(set(np.unique(f["failed"])) <= {0, 1}, f"{path}: failure flags other than 0 and 1")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("pvd")
    ap.add_argument("state")
    ap.add_argument("--ranks", type=int, default=1)
    ap.add_argument("--encoding", choices=["ascii", "binary", "compressed"], required=True)
    a = ap.parse_args()
    state = np.fromfile(a.state, dtype=RECORD)
    try:
        entries = collection(a.pvd, a.ranks)
        counts = set()
        for t, path in entries:
            grid = snapshot(path, a.ranks)
            vertices(grid, path)
            counts.add(grid.GetNumberOfPoints())
            if a.ranks == 1:
                time = vtk_to_numpy(grid.GetFieldData().GetArray("TIME"))[0]
                check(time == t, f"{path}: TIME {time!r}, its collection says {t!r}")
        check(len(counts) == 1, f"{a.pvd}: particle counts differ between snapshots: {sorted(counts)}")
        stored_as(entries[-1][1], a.encoding, a.ranks)
        against_state(last_snapshot(entries[-1][1], a.ranks), entries[-1][1], state)
    except (Failed, OSError, ET.ParseError) as e:
        sys.stderr.write(f"vtk-check: {e}\n")
        return 1
    print(f"vtk-check: {a.pvd}: {len(entries)} snapshots, {len(state)} particles, read by VTK and as the run's")
    return 0


if __name__ == "__main__":
    sys.exit(main())
