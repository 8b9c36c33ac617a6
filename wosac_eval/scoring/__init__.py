"""The scoring pipeline: one scenario (`scenario`), a whole submission (`submission`), where it runs
(`engines`: local processes or Ray) and the result document (`result`)."""
