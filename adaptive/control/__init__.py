"""The single-input self-tuning controller: its compiled step, the certainty-equivalence
designs (pole placement, LQ), the safe set and tracking law, extended least squares, the
known-model oracles and the compiled closed-loop rollout."""
