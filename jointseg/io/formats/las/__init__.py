"""LAS/LAZ through laspy: whole-file reading and writing (:mod:`.core`), the chunked reader and
writer (:mod:`.stream`), and where a segmented result goes in a LAS file (:mod:`.result`).
"""
