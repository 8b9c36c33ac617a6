"""The scoring pipeline: one scenario (`scenario`), a whole submission (`submission`: index, validate,
score, assemble, on any executor of `runtime.executors`) and the result document, written (`result`)
and read back (`result_reader`, for `results/` and the service)."""
