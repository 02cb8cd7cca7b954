"""SEAL: run-time steering of reasoning vision-language-action policies.

The package is laid out along the steering flow:

- ``seal.sim``      the world: LIBERO tasks, exact snapshots, a parallel env pool, rendering
- ``seal.policies`` who acts: reasoning policies that write sub-plans and action chunks
- ``seal.verify``   who judges: verifiers that check a predicted outcome against a sub-plan
- ``seal.steer``    the Hypothesize -> Predict -> Verify -> Commit loop
"""

__version__ = "0.1.0"
