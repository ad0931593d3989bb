"""Statistics of point sets: pure numpy functions of (..., n, 2) arrays; no samplers here."""
from .discrepancy import l2_star
from .distance import min_distance
from .spectrum import BIN_WIDTH, NUM_BINS, periodogram, radial_spectrum, spectrum_mae
from .structure import empty_elementary_fraction

__all__ = ["l2_star", "min_distance", "periodogram", "radial_spectrum", "spectrum_mae",
           "BIN_WIDTH", "NUM_BINS", "empty_elementary_fraction"]
