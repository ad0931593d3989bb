"""Power spectrum statistics: defined once in the runtime (numpy only), used here too."""
from diffsampler_rt.spectrum import BIN_WIDTH, NUM_BINS, periodogram, radial_spectrum, spectrum_mae

__all__ = ["BIN_WIDTH", "NUM_BINS", "periodogram", "radial_spectrum", "spectrum_mae"]
