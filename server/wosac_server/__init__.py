"""The deployable WOSAC scoring service (`wosac-server serve`): HTTP API, job store, scoring workers, web page.

It imports the `wosac_eval` library for everything it scores; this package
only stores uploads, queues jobs and serves results.
"""
