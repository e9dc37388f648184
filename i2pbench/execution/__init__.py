"""How work runs on this machine, whatever the stages are: in which process, for how long, on which device, and
what the user sees meanwhile.

- `isolation`: a frame's stages in a killable child process (`--isolate process`);
- `timeout`: the per-stage time limit (I2PBENCH_STAGE_TIMEOUT_S);
- `interrupts`: the user's Ctrl-C told apart from a KeyboardInterrupt plugin code raises;
- `lifeline`: a child process exits when its parent dies;
- `devices`: `--device` checked before any work starts;
- `progress`: progress bars and notes, silenced by `--quiet`.
"""
