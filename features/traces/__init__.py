"""Controller traces (docs/data-contract.md section 10): the contract's names, the reader of a
trace table (CSV, Parquet) and of a Parquet dataset partitioned by machine, axis and date, and
the validation every trace passes once at the edge."""
