"""The SPEC §4 claim verdicts, now ``sidewalk.report.claims``; this module is kept for existing imports."""

from sidewalk.report.claims import *  # every name in its __all__
from sidewalk.report.claims import __all__  # noqa: F401
