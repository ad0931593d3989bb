import pytest

torch = pytest.importorskip("torch")

from trainer.unet import UNet, UNetConfig  # noqa: E402

from .conftest import TINY_UNET  # noqa: E402


@pytest.mark.parametrize("padding", ["zeros", "circular"])
@pytest.mark.parametrize("k", [4, 5, 8, 24, 25, 30])
def test_any_grid_side(padding, k):
    net = UNet(UNetConfig(**TINY_UNET, padding=padding, coord_bits=2))
    x = torch.randn(2, 2, k, k)
    assert net(x, torch.tensor([0.0, 999.0])).shape == (2, 2, k, k)


def test_default_net_three_levels_odd_side():
    net = UNet(UNetConfig())
    assert net(torch.randn(1, 2, 25, 25), torch.tensor([10.0])).shape == (1, 2, 25, 25)


def test_attention_placement_is_a_setting():
    none = UNet(UNetConfig(**{**TINY_UNET, "attention_levels": (), "middle_attention": False}))
    every = UNet(UNetConfig(**{**TINY_UNET, "attention_levels": (0, 1)}))
    count = lambda m: sum(type(x).__name__ == "Attention" for x in m.modules())
    assert count(none) == 0 and count(every) > count(UNet(UNetConfig(**TINY_UNET)))


def test_bad_settings():
    with pytest.raises(ValueError, match="padding"):
        UNetConfig(padding="reflect")
    with pytest.raises(ValueError, match="attention_levels"):
        UNetConfig(attention_levels=(5,))


def test_coordinate_channels_encode_dyadic_position():
    net = UNet(UNetConfig(**TINY_UNET, coord_bits=2))
    c = net._coords(torch.zeros(1, 2, 4, 4))[0]
    assert c[0, 0].tolist() == [-1, 1, -1, 1]  # bit 0 of the column index
    assert c[1, 0].tolist() == [-1, -1, 1, 1]  # bit 1 of the column index


def test_axial_attention_mixes_rows_and_columns_only():
    from trainer.unet import AxialAttention
    torch.manual_seed(0)
    layer = AxialAttention(8, heads=2, groups=1)
    with torch.no_grad():  # projections start at zero (identity layer): make them act
        for p in layer.projs:
            p.weight.normal_()
    layer.norms = torch.nn.ModuleList([torch.nn.Identity(), torch.nn.Identity()])
    x = torch.randn(1, 8, 6, 6)
    y = x.clone()
    y[0, :, 2, 3] += 1.0  # one cell changes
    with torch.no_grad():
        diff = (layer(y) - layer(x)).abs().amax(dim=1)[0]
    # after row- then column-attention, a cell reaches its row and every column that the
    # row reached: here the whole grid can change, but only through those paths
    assert diff[2].min() > 0 and diff[:, 3].min() > 0
    rows_only = layer._rows(y, 0) - layer._rows(x, 0)
    touched = rows_only.abs().amax(dim=1)[0] > 0
    assert touched[2].all() and not touched[[0, 1, 3, 4, 5]].any()


def test_axial_levels_are_a_setting():
    net = UNet(UNetConfig(**TINY_UNET, axial_levels=(0,)))
    assert sum(type(m).__name__ == "AxialAttention" for m in net.modules()) == 3
    assert net(torch.randn(2, 2, 9, 9), torch.tensor([1.0, 500.0])).shape == (2, 2, 9, 9)
    with pytest.raises(ValueError, match="axial_levels"):
        UNetConfig(axial_levels=(3,))


def _active_attention(window):
    from trainer.unet import Attention
    torch.manual_seed(0)
    layer = Attention(8, heads=2, groups=2, window=window).eval()
    with torch.no_grad():  # the projection starts at zero (identity layer): make it act
        layer.proj.weight.normal_()
    return layer


@pytest.mark.parametrize("h", [3, 6])
def test_windowed_attention_is_global_when_the_grid_fits_one_window(h):
    glob, win = _active_attention(None), _active_attention(6)
    x = torch.randn(2, 8, h, h)
    with torch.no_grad():
        assert torch.equal(glob(x), win(x))


@pytest.mark.parametrize("h,m,s", [(7, 2, 4), (12, 2, 6), (13, 3, 5)])
def test_windowed_attention_attends_within_near_equal_windows(h, m, s):
    layer = _active_attention(6)
    x = torch.randn(1, 8, h, h)
    with torch.no_grad():
        got = layer(x)
        qkv = layer.qkv(layer.norm(x))  # the norm is over the whole grid
        ref = torch.zeros_like(x)
        for i in range(m):  # each window on its own, cut from the grid (last ones shorter)
            for j in range(m):
                cut = (slice(None), slice(None), slice(i * s, (i + 1) * s),
                       slice(j * s, (j + 1) * s))
                part = qkv[cut]
                b, c3, hh, ww = part.shape
                ref[cut] = layer._attend(part.reshape(b, c3, hh * ww), 8, None).reshape(
                    b, 8, hh, ww)
        ref = x + layer.proj(ref)
    assert torch.allclose(got, ref, atol=1e-5)


def test_attention_window_validated():
    with pytest.raises(ValueError, match="attention_window"):
        UNetConfig(attention_window=0)
