"""jointseg viewer (viser scene and job page). Depends on `server` and `jointseg`.

Its part of ``jointseg serve`` (job page, viewer process) is :func:`web.serve.service_parts`,
registered in the entry-point group ``jointseg.serve_parts``.
"""
