"""The only package that imports OCP: read, extract arrays, build and write.

Importing OCP costs about a second; the CLI imports this package only inside commands, so
``watertight --help`` stays fast.
"""
