"""Bytes <-> messages: TFRecord framing, scenario shards, submission files.

Modules: `tfrecord` (read/write TFRecord files), `scenarios` (find, stream and
index WOMD Scenario shards), `tar_format` (the tar format, streamed),
`archive` (what a submission file is, its shards read safely, and the upload
check), `submission_source` (the one walk over a submission: file, folder or
archive, and the handle every stage reads it through), `shards` (a shard's
bytes parsed or split into scenarios), `wire` (fields read from and written to
the wire directly), `decode` (one message from its bytes, a refused allocation told
from damaged bytes), `limits` (how far inputs may expand), `errors` (the
ParseError hierarchy).
"""
