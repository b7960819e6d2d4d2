# Writes the R files of this directory with R's own save() and saveRDS() from session.f64
# (the columns of session.csv.gz as raw float64, written by make_session.py).
# Run from the repository root: Rscript tests/data/rdata/make_rdata.R (see README.md).
dir <- "tests/data/rdata"
path <- file.path(dir, "session.f64")
names <- c("t", "gx", "gy", "gz", "ax", "ay", "az", "temp")
raw <- readBin(path, what = "double", n = file.size(path) / 8, size = 8, endian = "little")
imu <- as.data.frame(matrix(raw, ncol = length(names), dimnames = list(NULL, names)))
gain <- diag(3)
# a data.frame beside a distractor matrix: the reader asks for --variable
save(imu, gain, file = file.path(dir, "session.rda"), compress = "xz")
# an unnamed matrix, samples as rows: t gx gy gz ax ay az by position
head_m <- unname(as.matrix(imu[1:500, c("t", "gx", "gy", "gz", "ax", "ay", "az")]))
saveRDS(head_m, file.path(dir, "session_matrix.rds"), compress = "xz")
# a matrix with named columns in another order, beside a character vector
imu_named <- as.matrix(imu[1:500, c("ax", "ay", "az", "gx", "gy", "gz", "t")])
rownames(imu_named) <- NULL
note <- "recorded by imudiag simulate"
save(imu_named, note, file = file.path(dir, "session_named.RData"), compress = "gzip")
# a data.frame with a text and a factor column beside the sensor columns (50 rows)
tagged <- imu[1:50, c("t", "gx", "gy", "gz", "ax", "ay", "az")]
tagged$label <- rep(c("still", "turn"), 25)
tagged$pose <- factor(rep(c("up", "down"), each = 25))
saveRDS(tagged, file.path(dir, "session_tagged.rds"))
