"""VTK PolyData fixtures written by VTK itself (pip install vtk; VTK 9), for the .vtp reader's
tests: one open-ended tube (a vessel segment as a surface export has it) with its centerline
and radius array, in each encoding VTK and ParaView write.

    cd server/anatomy/tests/data/vtk && python3 make_fixtures.py
"""
import math

import vtk

# A curved centerline (mm) with a tapering radius.
points = vtk.vtkPoints()
radius = vtk.vtkDoubleArray()
radius.SetName("MaximumInscribedSphereRadius")
n = 24
for i in range(n):
    t = i / (n - 1)
    points.InsertNextPoint(40.0 * math.cos(t * 1.2), 40.0 * math.sin(t * 1.2), 15.0 * t)
    radius.InsertNextValue(3.0 - 1.0 * t)
line = vtk.vtkPolyLine()
line.GetPointIds().SetNumberOfIds(n)
for i in range(n):
    line.GetPointIds().SetId(i, i)
cells = vtk.vtkCellArray()
cells.InsertNextCell(line)
centerline = vtk.vtkPolyData()
centerline.SetPoints(points)
centerline.SetLines(cells)
centerline.GetPointData().AddArray(radius)
centerline.GetPointData().SetActiveScalars("MaximumInscribedSphereRadius")

tube = vtk.vtkTubeFilter()
tube.SetInputData(centerline)
tube.SetVaryRadiusToVaryRadiusByAbsoluteScalar()
tube.SetNumberOfSides(16)
tube.CappingOff()
triangles = vtk.vtkTriangleFilter()
triangles.SetInputConnection(tube.GetOutputPort())
triangles.Update()
surface = vtk.vtkPolyData()
surface.DeepCopy(triangles.GetOutput())
surface.GetPointData().Initialize()  # geometry only


def write(data, name, mode, compress, header64=False, encode=True):
    w = vtk.vtkXMLPolyDataWriter()
    w.SetInputData(data)
    w.SetFileName(name)
    {"ascii": w.SetDataModeToAscii, "binary": w.SetDataModeToBinary, "appended": w.SetDataModeToAppended}[mode]()
    if compress:
        w.SetCompressorTypeToZLib()
    else:
        w.SetCompressorTypeToNone()
    if header64:
        w.SetHeaderTypeToUInt64()
    else:
        w.SetHeaderTypeToUInt32()
    w.SetEncodeAppendedData(encode)
    assert w.Write() == 1


for data, stem in [(surface, "tube"), (centerline, "centerline")]:
    write(data, f"{stem}_ascii.vtp", "ascii", False)
    write(data, f"{stem}_binary_zlib.vtp", "binary", True)
    write(data, f"{stem}_binary_zlib_uint64.vtp", "binary", True, header64=True)
    write(data, f"{stem}_binary_raw.vtp", "binary", False)
    write(data, f"{stem}_appended_base64_zlib.vtp", "appended", True)
    write(data, f"{stem}_appended_raw_zlib.vtp", "appended", True, encode=False)
    write(data, f"{stem}_appended_raw_uint64.vtp", "appended", False, header64=True, encode=False)
print(vtk.vtkVersion.GetVTKVersion())

for binary, name in [(False, "tube_ascii.ply"), (True, "tube_binary.ply")]:
    w = vtk.vtkPLYWriter()
    w.SetInputData(surface)
    w.SetFileName(name)
    if binary:
        w.SetFileTypeToBinary()
        w.SetDataByteOrderToLittleEndian()
    else:
        w.SetFileTypeToASCII()
    assert w.Write() == 1
