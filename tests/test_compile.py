import pytest
import torch

from datt.compile import compile_or_eager


def test_falls_back_to_eager_when_the_backend_fails():
    def broken_backend(gm, example_inputs):
        raise RuntimeError("no C++ compiler here")

    def f(x):
        return x * 2 + 1

    g = compile_or_eager(f, backend=broken_backend)
    with pytest.warns(UserWarning, match="torch.compile failed for f"):
        assert torch.equal(g(torch.ones(3)), torch.full((3,), 3.0))
    assert torch.equal(g(torch.zeros(2)), torch.ones(2))  # stays eager, no second warning


def test_real_errors_still_raise():
    def f(x):
        return x @ x  # 1-D @ 1-D fine, 3-D mismatch raises

    g = compile_or_eager(f, backend="eager")
    with pytest.raises(RuntimeError):
        with pytest.warns(UserWarning):
            g(torch.ones(2, 3))
