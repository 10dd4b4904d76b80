-- An id for each world a database holds: made with its world row, so a
-- restore (which writes the row anew) gives the world a new one. A server
-- reads it at start and compares it in every commit: a world replaced
-- under it (a restore that got in while its lock connection was lost)
-- stops it, even where the restored world ends at the seq it is at. A
-- cluster's tickets are signed for it, so one world's tickets are refused
-- by another's nodes, and by the same world's after a restore.
ALTER TABLE world ADD COLUMN generation text NOT NULL DEFAULT gen_random_uuid()::text;
