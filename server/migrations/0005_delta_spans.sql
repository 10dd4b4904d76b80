-- Store format 3: a chunk delta may span several versions (a tick stores
-- one delta per changed chunk, from its version before the tick to the
-- last). Format-2 rows are valid format-3 rows; only the version moves, so
-- a build that reads format 2 only refuses the database from now on.
UPDATE world SET format_version = 3 WHERE format_version = 2;
