"""watertight: trimmed CAD models (STEP, IGES) to watertight models of untrimmed Bezier patches.

Layout (the data flows top to bottom):

- ``watertight_cli.occ``   -- the only package that imports OCP: read, extract arrays, build, write.
- ``watertight_cli.model`` -- the model as plain numpy arrays (faces, loops, coedges, edges).
- ``watertight_cli.core``  -- the numeric core: Bezier / B-spline algebra on arrays, no OCP.
- ``watertight_cli.gaps``  -- gap measurement on the array model.
- ``watertight_cli.cli``   -- the click command line; converts library errors to one-line messages.
"""

__version__ = "0.1.0"
