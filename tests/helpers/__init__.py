"""Helpers shared by the test modules (not tests themselves): paths that do not depend on where a test file sits,
format encoders written from each file format's definition, the thin Gaussian shells and tiny training settings.

``tests/`` is on ``sys.path`` (``pythonpath`` in setup.cfg's ``[tool:pytest]``), so a test in any subfolder of
``tests/`` imports these as ``from helpers.paths import REPO``. Test modules never import each other.
"""
