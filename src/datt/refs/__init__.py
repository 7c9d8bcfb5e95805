"""Reference trajectory families (see :mod:`datt.refs.base`)."""

from datt.refs.base import RefFamily, piecewise_linear
from datt.refs.composite import Fixed, Mixed, Seeded
from datt.refs.csv import CsvReference, load_csv_reference
from datt.refs.poly import ChainedPoly, Poly
from datt.refs.polygon import Polygon
from datt.refs.zigzag import Zigzag

__all__ = [
    "RefFamily",
    "piecewise_linear",
    "Zigzag",
    "Poly",
    "ChainedPoly",
    "Polygon",
    "Fixed",
    "Mixed",
    "Seeded",
    "CsvReference",
    "load_csv_reference",
]
