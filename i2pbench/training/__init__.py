"""Training the learned stages of a combination (`i2pbench train`; docs/training.md).

- `loop`: the `Trainer` (DataLoader, optimiser steps and schedule, validation through the frame path);
- `runtime`: where it runs (device, ranks under torchrun and DDP, deterministic kernels, `torch.compile`);
- `trainable`: what it changes (the learned stages less the frozen ones, the optimiser);
- `checkpoints`: the checkpoint, the `best` one and the resume file, and resuming from them;
- `lineage`: what the weights were trained on, and the earlier phases a fine-tuning continues;
- `steplog`: the JSONL step log and TensorBoard events;
- `config`: a run's settings (`TrainConfig`), the one source of `train`'s defaults, importable without torch;
- `samples`: training samples as a torch Dataset, with per-frame caches on disk;
- `batching`: how the learned stages take a padded batch of frames;
- `mix`: several datasets in one run (`--mix`); `augment`, `lidar_dropout`: per-sample augmentations.
"""
