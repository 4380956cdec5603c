"""PCL's PCD: reading and writing (:mod:`.core`), and the LZF decompression its
``binary_compressed`` bodies need (:mod:`.lzf`).
"""
