"""Reading VTK files back independently of the writer: VTK's own XML reader for .vtu, a strict parse of .pvd."""

import xml.etree.ElementTree as ET

import numpy as np
import pytest


def read_vtu(path):
    """(points [N, 3], {name: point data}, number of cells) of a .vtu, through VTK's own XML reader."""
    vtk = pytest.importorskip("vtk")
    from vtk.util.numpy_support import vtk_to_numpy

    reader = vtk.vtkXMLUnstructuredGridReader()
    reader.SetFileName(str(path))
    reader.Update()
    grid = reader.GetOutput()
    pd = grid.GetPointData()
    data = {pd.GetArrayName(i): vtk_to_numpy(pd.GetArray(i)) for i in range(pd.GetNumberOfArrays())}
    points = vtk_to_numpy(grid.GetPoints().GetData()) if grid.GetNumberOfPoints() else np.zeros((0, 3))
    return points, data, grid.GetNumberOfCells()


def read_pvd(path):
    """[(time, file)] of a ParaView collection, read strictly: the root, its one Collection, each DataSet."""
    root = ET.parse(path).getroot()
    assert root.tag == "VTKFile" and root.attrib["type"] == "Collection"
    (coll,) = list(root)
    assert coll.tag == "Collection"
    return [(float(d.attrib["timestep"]), d.attrib["file"]) for d in coll if d.tag == "DataSet"]
