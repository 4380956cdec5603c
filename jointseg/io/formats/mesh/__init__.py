"""Meshes (GLB/glTF, OBJ, PLY with faces) read through trimesh and sampled to points
(:mod:`.core`), with the glTF container checked first (:mod:`.gltf`) and the sampling on the
triangles, coloured and labelled (:mod:`.sample`). Read only.
"""
