"""Training the learned stages of a combination (`i2pbench train`; docs/training.md).

- `trainer`: the loop (DataLoader, optimiser and schedule, DDP, checkpoints, validation through the frame path);
- `config`: a run's settings (`TrainConfig`), the one source of `train`'s defaults, importable without torch;
- `samples`: training samples as a torch Dataset, with per-frame caches on disk;
- `batching`: how the learned stages take a padded batch of frames;
- `mix`: several datasets in one run (`--mix`); `augment`, `lidar_dropout`: per-sample augmentations.
"""
