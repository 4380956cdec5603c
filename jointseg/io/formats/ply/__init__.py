"""PLY: the header and whole-file reading and writing (:mod:`.core`), the chunked reader and
writer for big binary files (:mod:`.stream`), and chosen columns read block by block
(:mod:`.blocks`, the viewer's reader). A PLY with faces is a mesh, read by
:mod:`jointseg.io.formats.mesh`; the format table (:mod:`jointseg.io.formats`) picks which.
"""
