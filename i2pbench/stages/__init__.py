"""How stages are called: one caller and what it checks and returns.

- `calling`: `call_stage`, the one caller (`Pipeline.run`, the batched training path and the conformance kit use it):
  the declared view of the frame, the timed call, the contract check;
- `contracts`: each stage kind's contract on its output;
- `trace`: what a frame's stages returned (`StageRecord`, `FrameOutcome`) and what each later stage is handed;
- `config`: a component's configuration merged over its defaults and checked.
"""
