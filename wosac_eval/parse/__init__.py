"""Bytes -> messages: TFRecord framing, scenario shards, submission archives.

Modules: `tfrecord` (read/write TFRecord files), `scenarios` (find, stream and
index WOMD Scenario shards), `archive` (submission shards from files, folders
and tar archives), `errors` (the ParseError hierarchy).
"""
