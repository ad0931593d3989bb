"""diffsampler plot and diffsampler_rt.plot (matplotlib extra)."""
import numpy as np
import pytest

pytest.importorskip("matplotlib")

from diffsampler_rt.cli import main  # noqa: E402
from diffsampler_rt.plot import plot_sets  # noqa: E402


@pytest.mark.slow
def test_plot_from_a_model(tmp_path):
    out = tmp_path / "fig.png"
    assert main(["plot", "rank1", "64", "--count", "2", "--seed", "0", "-o", str(out)]) == 0
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_plot_from_points(tmp_path):
    pts = np.random.default_rng(0).random((3, 100, 2))
    np.save(tmp_path / "white.npy", pts)
    out = tmp_path / "fig.svg"
    assert main(["plot", str(tmp_path / "white.npy"), "-o", str(out)]) == 0
    assert b"<svg" in out.read_bytes()[:500]


def test_plot_errors(tmp_path, capsys):
    assert main(["plot", "rank1", "-o", str(tmp_path / "x.png")]) == 2
    assert "needs N" in capsys.readouterr().err
    assert main(["plot", "rank1", "15", "-o", str(tmp_path / "x.png")]) == 2
    assert "too small" in capsys.readouterr().err
    with pytest.raises(ValueError, match="shape"):
        plot_sets(np.zeros((4, 3)))
    # NaNs or points outside the square make no spectrum: said, not drawn blank
    bad = np.random.default_rng(0).random((2, 64, 2))
    bad[1, 3, 0] = np.nan
    with pytest.raises(ValueError, match=r"points has 1 non-finite coordinate \(NaN or inf\)"):
        plot_sets(bad)
    with pytest.raises(ValueError, match="reference must lie in the unit square.*to 2"):
        plot_sets(bad[0], reference=2 * np.ones((1, 64, 2)))
    np.save(tmp_path / "outside.npy", bad[0] - 0.5)
    assert main(["plot", str(tmp_path / "outside.npy"), "-o", str(tmp_path / "x.png")]) == 2
    assert "points must lie in the unit square [0, 1]^2, got coordinates from -0." in (
        capsys.readouterr().err)


def test_reference_curve_and_docstring():
    import doctest

    from diffsampler_rt import plot
    fig = plot_sets(np.random.default_rng(1).random((64, 2)),
                    reference=np.random.default_rng(2).random((2, 64, 2)))
    assert [line.get_label() for line in fig.axes[2].lines][:2] == ["reference", "points"]
    assert doctest.testmod(plot).failed == 0
