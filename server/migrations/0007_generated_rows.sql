-- Store format 4 on PostgreSQL: a chunk row may say "generated" (version
-- 0, body 0x00): the chunk is the generator's output, and its first
-- changes are deltas after it, the first one to version 1. Its own
-- number, after 6 (which moved the format version only), so that a
-- build that knows 6 migrations refuses a database with such rows.
ALTER TABLE chunks DROP CONSTRAINT IF EXISTS chunks_version_check;
ALTER TABLE chunks ADD CONSTRAINT chunks_version_check
    CHECK (version > 0 OR (version = 0 AND body = '\x00'::bytea));
ALTER TABLE chunk_deltas DROP CONSTRAINT IF EXISTS chunk_deltas_to_version_check;
ALTER TABLE chunk_deltas ADD CONSTRAINT chunk_deltas_to_version_check
    CHECK (to_version > 0);
