-- A node asking for a region another node holds (an edit it must apply
-- reaches across the border into that region): the holder lets it go at
-- its next renewal once its own players have not edited it for
-- [cluster] handoff_idle_ms, and the asking node claims it at the next
-- edit. A claim clears the ask; one older than a lease is ignored.
ALTER TABLE regions ADD COLUMN wanted_by text;
ALTER TABLE regions ADD COLUMN wanted_at timestamptz;
CREATE INDEX regions_wanted ON regions (owner) WHERE wanted_by IS NOT NULL;
