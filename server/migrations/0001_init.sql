-- Strata's PostgreSQL store, first layout (server/src/store/pg).
-- Unsigned Rust integers are stored in bigint: seqs and versions must stay
-- below 2^63 (the store refuses larger ones); the seed keeps its 64 bits
-- as a two's-complement bigint.

-- World metadata, one row. last_seq is the seq of the last committed edit;
-- log_base is the seq of the snapshot a restored world started from.
CREATE TABLE world (
    id                smallint PRIMARY KEY CHECK (id = 1),
    format_version    integer  NOT NULL,
    seed              bigint   NOT NULL,
    generator_version bigint   NOT NULL,
    generator_params  text     NOT NULL,
    last_seq          bigint   NOT NULL CHECK (last_seq >= 0),
    log_base          bigint   NOT NULL DEFAULT 0 CHECK (log_base >= 0)
);

-- Region side in chunks, fixed for the world's life: every chunk row
-- carries its region, the unit a cluster leases to one node.
CREATE TABLE layout (
    id            smallint PRIMARY KEY CHECK (id = 1),
    region_chunks integer  NOT NULL CHECK (region_chunks > 0)
);

-- Chunk records: version and chunk codec bytes.
CREATE TABLE chunks (
    x        integer NOT NULL,
    y        integer NOT NULL,
    z        integer NOT NULL,
    region_x integer NOT NULL,
    region_z integer NOT NULL,
    version  bigint  NOT NULL CHECK (version > 0),
    body     bytea   NOT NULL,
    PRIMARY KEY (x, y, z)
);
CREATE INDEX chunks_by_region ON chunks (region_x, region_z);

-- Deltas committed past each chunk's record (bincode ChunkDelta), folded
-- into the record by checkpoints.
CREATE TABLE chunk_deltas (
    x          integer NOT NULL,
    y          integer NOT NULL,
    z          integer NOT NULL,
    to_version bigint  NOT NULL CHECK (to_version > 1),
    region_x   integer NOT NULL,
    region_z   integer NOT NULL,
    body       bytea   NOT NULL,
    PRIMARY KEY (x, y, z, to_version)
);
CREATE INDEX chunk_deltas_by_region ON chunk_deltas (region_x, region_z);

-- The edit log (bincode LogEntry), by seq.
CREATE TABLE edit_log (
    seq   bigint PRIMARY KEY CHECK (seq > 0),
    entry bytea  NOT NULL
);

-- Named blobs: protected zones, the access list.
CREATE TABLE blobs (
    name text  PRIMARY KEY,
    body bytea NOT NULL
);

-- Players' last feet positions, fixed point.
CREATE TABLE players (
    name text    PRIMARY KEY,
    x    integer NOT NULL,
    y    integer NOT NULL,
    z    integer NOT NULL
);
