"""The bundled arch-to-cow surface (../arch-to-cow/vessels.obj, MIT, stEVE_bench) opened as
surfaces exported from 3D Slicer, VMTK or SOFA examples arrive: everything beyond x = -60 mm
removed (the two vessels running there, the wider where devices enter, are left open), and
the rounded end of a neck vessel removed (the faces wholly beyond a plane through the end of
its computed centerline, normal to it, within three radii), leaving its rim open: three open
ends. The neck vessel's end comes from `ends.json` (printed by `cargo test --release -p
cathlab-imaging --test surface_centerlines print_free_ends -- --ignored --nocapture`; other
ends of this model, trimmed so, open into neighbouring vessels rather than outside).
Written by VTK as ParaView saves by default: appended raw data, zlib-compressed,
millimetres, in the surface's own frame.

    pip install vtk numpy
    cd data/anatomy/arch-to-cow-open && python3 make_open.py
"""
import json

import numpy as np
import vtk

reader = vtk.vtkOBJReader()
reader.SetFileName("../arch-to-cow/vessels.obj")
triangles = vtk.vtkTriangleFilter()
triangles.SetInputConnection(reader.GetOutputPort())
triangles.Update()
mesh = triangles.GetOutput()
points = np.array([mesh.GetPoint(i) for i in range(mesh.GetNumberOfPoints())])
faces = np.array(
    [[mesh.GetCell(i).GetPointId(k) for k in range(3)] for i in range(mesh.GetNumberOfCells())]
)

with open("ends.json") as f:
    ends = {e["branch"]: e for e in json.load(f)}
# The descending aorta, opened 60 mm short of its (irregular) distal end: every face wholly
# beyond x = -60 mm goes.
keep = ~(points[faces][:, :, 0] > -60.0).all(axis=1)
print(f"descending aorta: {int((~keep).sum())} faces removed beyond x = -60 mm")
for name in ["vessel_32"]:
    e = ends[name]
    p, t, r = np.array(e["point"]), np.array(e["tangent"]), e["radius_mm"]
    # A face goes when all its corners lie beyond the plane and within three radii.
    corners = points[faces]
    beyond = ((corners - p) @ t > 0.0).all(axis=1)
    near = (np.linalg.norm(corners - p, axis=2) < 3.0 * r).all(axis=1)
    keep &= ~(beyond & near)
    print(f"{name}: {int((beyond & near).sum())} faces removed at {p} (radius {r} mm)")

polys = vtk.vtkCellArray()
for f in faces[keep]:
    polys.InsertNextCell(3, [int(i) for i in f])
out = vtk.vtkPolyData()
out.SetPoints(mesh.GetPoints())
out.SetPolys(polys)
# A vessel's tip may come loose whole (a ring of faces removed): keep the one piece.
merged = vtk.vtkCleanPolyData()
merged.SetInputData(out)
largest = vtk.vtkPolyDataConnectivityFilter()
largest.SetInputConnection(merged.GetOutputPort())
largest.SetExtractionModeToLargestRegion()
clean = vtk.vtkCleanPolyData()
clean.SetInputConnection(largest.GetOutputPort())
clean.Update()
writer = vtk.vtkXMLPolyDataWriter()
writer.SetInputData(clean.GetOutput())
writer.SetFileName("vessels_open.vtp")
writer.SetDataModeToAppended()
writer.SetEncodeAppendedData(False)
writer.SetCompressorTypeToZLib()
assert writer.Write() == 1
print(clean.GetOutput().GetNumberOfPolys(), "triangles")
