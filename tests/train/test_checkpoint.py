import pytest
import torch

from datt.checkpoint import FORMAT, load_checkpoint, save_checkpoint
from datt.errors import ConfigError


def test_round_trip_and_weights_only(tmp_path):
    payload = {"actor": {"w": torch.arange(3.0)}, "frames": 7, "config_yaml": "a: 1\n"}
    path = save_checkpoint(tmp_path / "last.pt", payload)
    data = load_checkpoint(path)
    assert data["format"] == FORMAT and data["frames"] == 7 and torch.equal(data["actor"]["w"], torch.arange(3.0))
    assert load_checkpoint(tmp_path)["frames"] == 7  # a run dir means its last.pt
    assert [p.name for p in tmp_path.iterdir()] == ["last.pt"]  # no temp files left


def test_failed_write_keeps_previous_checkpoint(tmp_path):
    save_checkpoint(tmp_path / "last.pt", {"frames": 1})

    class Boom:
        def __reduce__(self):
            raise RuntimeError("disk full")

    with pytest.raises(RuntimeError, match="disk full"):
        save_checkpoint(tmp_path / "last.pt", {"frames": 2, "bad": Boom()})
    assert load_checkpoint(tmp_path / "last.pt")["frames"] == 1
    assert [p.name for p in tmp_path.iterdir()] == ["last.pt"]


@pytest.mark.parametrize(
    "content, message",
    [(b"not a checkpoint at all", "is not a readable checkpoint"), (None, "not found")],
)
def test_corrupt_or_missing_checkpoint_is_one_line_error(tmp_path, content, message):
    path = tmp_path / "x.pt"
    if content is not None:
        path.write_bytes(content)
    with pytest.raises(ConfigError) as info:
        load_checkpoint(path, key="checkpoint")
    assert str(info.value).startswith("checkpoint:") and message in str(info.value) and "\n" not in str(info.value)


def test_truncated_and_foreign_checkpoints(tmp_path):
    good = save_checkpoint(tmp_path / "good.pt", {"frames": 3})
    truncated = tmp_path / "trunc.pt"
    truncated.write_bytes(good.read_bytes()[:-40])
    with pytest.raises(ConfigError, match="not a readable checkpoint"):
        load_checkpoint(truncated)
    foreign = tmp_path / "foreign.pt"
    torch.save({"state_dict": {}}, foreign)
    with pytest.raises(ConfigError, match="not a datt checkpoint"):
        load_checkpoint(foreign)
    evil = tmp_path / "evil.pt"
    torch.save({"format": FORMAT, "obj": ConfigError("x")}, evil)  # arbitrary objects are refused
    with pytest.raises(ConfigError, match="not a readable checkpoint"):
        load_checkpoint(evil)
