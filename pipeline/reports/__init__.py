"""Reports, charts and pages: what a job's result looks like on paper and on screen (HTML,
PDF, PNG). They read results and frames; they compute no figures of their own."""
