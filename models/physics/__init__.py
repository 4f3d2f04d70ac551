"""Named physical effects and the feed-drive twin that measures itself like a laser."""
