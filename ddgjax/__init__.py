"""ddgjax (package init is finalised by the lead once all subpackages exist)."""
