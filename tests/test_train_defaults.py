"""`i2pbench train`'s options take their defaults from TrainConfig, so the command line and the library train alike."""

import dataclasses

from i2pbench.cli import build_parser
from i2pbench.commands.train import CONFIG_OPTIONS, train_config
from i2pbench.training.config import TrainConfig


def parse(*argv: str):
    return build_parser(full=("train",)).parse_args(["train", "--out", "w.pt", *argv])


def test_every_setting_is_an_option_or_derived_by_the_command():
    assert {f.name for f in dataclasses.fields(TrainConfig)} == set(CONFIG_OPTIONS) | {"cache_dir", "epochs"}


def test_with_no_options_the_command_trains_with_the_library_defaults():
    config = train_config(parse(), "cpu")
    assert config == dataclasses.replace(TrainConfig(), device="cpu", cache_dir="runs/cache/train")


def test_each_option_reaches_its_setting():
    args = parse(
        "--steps", "7", "--batch-size", "2", "--accumulate", "3", "--workers", "0", "--lr", "0.5", "--warmup-steps",
        "4", "--schedule", "cosine", "--grad-clip", "2", "--augment", "photometric", "--amp", "bf16",
        "--deterministic", "--compile", "aot_eager", "--checkpoint-every", "5", "--validate-every", "6",
        "--val-frames", "8", "--seed", "9", "--cache-dir", "none", "--epochs", "1.5",
    )  # fmt: skip
    config = train_config(args, "cuda:0")
    assert config == TrainConfig(
        steps=7, batch_size=2, accumulate=3, workers=0, lr=0.5, warmup_steps=4, schedule="cosine", grad_clip=2.0,
        augment="photometric", amp="bf16", deterministic=True, compile="aot_eager", checkpoint_every=5,
        validate_every=6, val_frames=8, seed=9, device="cuda:0", cache_dir=None, epochs=True,
    )  # fmt: skip
