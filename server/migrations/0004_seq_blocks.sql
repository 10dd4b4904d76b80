-- Seq blocks (server/src/store/pg/seqs.rs): in a cluster each node numbers
-- its edits from a block of seqs reserved here, so two nodes writing at
-- once never hand out the same seq. world.seq_reserved is the end of the
-- newest block; seq_blocks records where each block starts, so `check`
-- can tell a jump to a new block from a lost log record.
ALTER TABLE world ADD COLUMN seq_reserved bigint NOT NULL DEFAULT 0 CHECK (seq_reserved >= 0);
CREATE TABLE seq_blocks (
    first_seq   bigint      PRIMARY KEY CHECK (first_seq > 0),
    node        text        NOT NULL,
    reserved_at timestamptz NOT NULL DEFAULT now()
);
-- Per region: the seq of its last committed edit (fenced commits keep each
-- region's seqs rising across owners), and the address clients reach the
-- owner at (`[cluster] advertise`), for edits refused as held elsewhere.
ALTER TABLE regions ADD COLUMN last_seq bigint NOT NULL DEFAULT 0 CHECK (last_seq >= 0);
ALTER TABLE regions ADD COLUMN owner_addr text;
