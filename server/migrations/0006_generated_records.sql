-- Store format 4: a chunk record may say "generated" (the chunk's first
-- changes are deltas from the generator's output). This step moves the
-- version only; migration 7 lets PostgreSQL rows say "generated". A build
-- that reads format 3 refuses the database from now on.
UPDATE world SET format_version = 4 WHERE format_version = 3;
