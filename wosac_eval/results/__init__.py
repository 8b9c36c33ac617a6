"""Libraries over scored results, for the command line and the service alike: compare two runs and gate
on regressions (`compare`, written out by `compare_text`; `stats`, `stratify`, `per_object_compare`),
render an HTML report (`report`), draw a scene and its rollouts (`scene_plot`), synthetic results with
known differences for tests, benchmarks and the gate demo (`synthetic_results`). The result document is
written and read in `scoring` (`result`, `result_reader`)."""
