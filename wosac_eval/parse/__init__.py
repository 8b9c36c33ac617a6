"""Bytes <-> messages: TFRecord framing, scenario shards, submission files.

Modules: `tfrecord` (read/write TFRecord files), `scenarios` (find, stream and
index WOMD Scenario shards), `tar_format` (the tar format, streamed),
`archive` (a submission file's shards read safely, member by member, and the
upload check), `decompress` (what a file's bytes are, and their decompressed
stream under a limit), `member_names` (which names are shards, skipped or
refused), `shard_walk` (the one walk over a submission: file, folder or
archive), `submission_source` (the handle every stage reads it through),
`shards` (a shard's
bytes parsed or split into scenarios), `wire` (fields read from and written to
the wire directly), `decode` (one message from its bytes, a refused allocation told
from damaged bytes), `limits` (how far inputs may expand), `errors` (the
ParseError hierarchy).
"""
