-- Store format 4: a chunk row may say "generated" (version 0, body 0x00):
-- the chunk is the generator's output, and its first changes are deltas
-- after it, the first one to version 1. Older rows are valid format-4
-- rows; only the version moves, so a build that reads format 3 only
-- refuses the database from now on.
ALTER TABLE chunks DROP CONSTRAINT chunks_version_check;
ALTER TABLE chunks ADD CONSTRAINT chunks_version_check
    CHECK (version > 0 OR (version = 0 AND body = '\x00'::bytea));
ALTER TABLE chunk_deltas DROP CONSTRAINT chunk_deltas_to_version_check;
ALTER TABLE chunk_deltas ADD CONSTRAINT chunk_deltas_to_version_check
    CHECK (to_version > 0);
UPDATE world SET format_version = 4 WHERE format_version = 3;
