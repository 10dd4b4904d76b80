-- Store format 4: a sled chunk record may say "generated" (the chunk's
-- first changes are deltas from the generator's output). PostgreSQL stores
-- first changes whole, so its rows are unchanged; only the version moves,
-- so a build that reads format 3 only refuses the database from now on.
UPDATE world SET format_version = 4 WHERE format_version = 3;
