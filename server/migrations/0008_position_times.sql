-- When the server last knew each player at its stored position (ms since
-- the Unix epoch): a node that starts from the stored positions refuses
-- tickets issued before it. 0 for positions stored before this was kept.
ALTER TABLE players ADD COLUMN known_ms bigint NOT NULL DEFAULT 0
    CHECK (known_ms >= 0);
