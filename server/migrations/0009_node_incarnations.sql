-- The process running as each node_id now. Every start of a node writes a
-- new incarnation, and every lease renewal checks that the row is still
-- its own: a second live process started under the same name makes the
-- older one stop, instead of the two taking regions from each other.
CREATE TABLE nodes (
    node_id     text PRIMARY KEY,
    incarnation bigint NOT NULL,
    started_at  timestamptz NOT NULL DEFAULT now(),
    seen_at     timestamptz NOT NULL DEFAULT now()
);
