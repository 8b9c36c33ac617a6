"""The scoring pipeline: one scenario (`scenario`), a whole submission (`submission`: index, validate,
score, assemble, on any executor of `runtime.executors`) and the result document (`result`)."""
