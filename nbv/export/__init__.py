"""nbv.export: what leaves the tool in the formats other tools read.

=============================  ===============================================================================
module                         what
=============================  ===============================================================================
:mod:`nbv.export.solid`        the filled solid the probes flowed against: a voxel grid (HDF5) and a closed
                               surface mesh (.ply, .obj, .glb, .stl) by marching cubes (scikit-image, trimesh)
:mod:`nbv.export.particles`    fluid frames of OUT.h5 or of RESULT.h5's recorded probes as VTK point clouds
                               (.vtu, one per saved frame, written by meshio) and a ParaView ``.pvd`` series
=============================  ===============================================================================

Neither module imports Taichi or torch: they read the HDF5 files and the arrays the probe run left.
"""
