"""Bytes <-> messages: TFRecord framing, scenario shards, submission archives.

Modules: `tfrecord` (read/write TFRecord files), `scenarios` (find, stream and
index WOMD Scenario shards), `archive` (submission shards from files, folders
and tar archives), `submission_writer` (write a submission: shards, folder or
archive), `wire` (fields read from and written to the wire directly), `errors`
(the ParseError hierarchy).
"""
