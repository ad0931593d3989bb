"""Statistics of point sets: pure numpy functions of (..., n, 2) arrays; no samplers here."""
from .compare import compare, format_table
from .discrepancy import gl2, l2_star
from .distance import (min_distance, nearest_neighbour_distances, nearest_neighbour_percentile,
                       pair_correlation, spacing_coefficient)
from .ot_energy import ot_energy
from .integration import Gaussians, Heavisides, integration_mse
from .spectrum import BIN_WIDTH, NUM_BINS, periodogram, radial_spectrum, spectrum_mae
from .structure import empty_elementary_fraction, stratified_projections, t_value

__all__ = ["l2_star", "gl2", "min_distance", "nearest_neighbour_distances", "nearest_neighbour_percentile", "pair_correlation", "spacing_coefficient", "periodogram", "radial_spectrum", "spectrum_mae",
           "BIN_WIDTH", "NUM_BINS", "empty_elementary_fraction", "t_value",
           "stratified_projections", "Gaussians", "Heavisides", "integration_mse", "compare", "ot_energy",
           "format_table"]
