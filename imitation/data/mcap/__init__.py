"""The MCAP demo file: the format's constants and channel layout (`format`), the raw MCAP record
and chunk parser (`records`), the writer (`writer`) and the reader with its salvage scan
(`reader`). docs/FORMAT.md specifies the format; `imitation.data.dataset` reads several files as
one dataset."""
