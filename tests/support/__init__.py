"""What the tests share besides fixtures: plain helpers imported by name, e.g.
``from tests.support.service_process import running``.

Fixtures stay in the conftest.py files (tests/conftest.py for the whole suite, tests/<package>/
conftest.py for one package); everything else two test modules use lives here, one module a
subject: real service processes (service_process), hostile upload files (hostile_files), result
files for the viewer (result_files), the viewer's pages, screenshots and camera (viewer_pages,
shots, camera_math), downloaded files (download_checks), random scans (scans) and probability
rows (probs).
"""
