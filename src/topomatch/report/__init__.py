"""Reports from run directories: the track's figures and table, and an offline HTML page.

``build_report(runs, out_dir)`` reads what ``topomatch bench`` stored and never matches
or scores again. This is the only package that uses matplotlib, and it imports it
inside the functions that draw, so ``import topomatch`` (and this package) stays free
of plotting libraries. See ``docs/report.md``.
"""

from topomatch.report.build import build_report

__all__ = ["build_report"]
