"""Stages: what each kind takes and returns, how a combination of them runs, and how each is called and checked.

- `components`: the stage base classes and the stage kinds (`STAGES`); `learned`: the base of stages with
  parameters and of those run on padded batches;
- `pipeline`: a combination checked before any frame runs, then run one frame at a time;
- `calling`: `call_stage`, the one caller (`Pipeline.run`, the batched training path and the conformance kit use it):
  the declared view of the frame, the timed call, the contract check;
- `contracts`: each stage kind's contract on its output;
- `trace`: what a frame's stages returned (`StageRecord`, `FrameOutcome`) and what each later stage is handed;
- `config`: a component's configuration merged over its defaults and checked.
"""
