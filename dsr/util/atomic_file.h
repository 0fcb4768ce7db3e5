// Atomic output: write to a temporary file in the destination's folder, then rename(2) it
// into place. A reader never sees a half-written file, and a failed or interrupted write
// leaves any previous file untouched.
#ifndef DSR_UTIL_ATOMIC_FILE_H_
#define DSR_UTIL_ATOMIC_FILE_H_

#include <functional>
#include <string>

namespace dsr {

// Writes `contents` to `path` atomically. On failure returns false with `error` naming
// the path and the reason (folder missing, not writable, disk full, ...).
bool WriteFileAtomically(const std::string& path,
                         const std::string& contents,
                         std::string* error);

// For writers that need a file name (ITK, OpenCV): calls `write(temp_path)`, where
// temp_path is in the same folder and keeps the extension of `path` (".nii.gz" included),
// then renames it to `path`. `write` returns false with its own error to abort; the
// temporary file is removed on any failure.
bool WriteViaTemporaryFile(const std::string& path,
                           const std::function<bool(const std::string& temp_path,
                                                    std::string* error)>& write,
                           std::string* error);

// For writers that produce several files, such as the detached-header formats .mhd and
// .nhdr (header plus data file named after it): calls `write(temp_path)`, where temp_path
// has the file name of `path` but lies in a new private folder next to it, then moves every
// file `write` created into `path`'s folder (data files first, `path` last, so the header
// never names missing data) and removes the private folder. Each move is atomic; files of
// the same names in `path`'s folder are replaced. If `write` fails, nothing is moved.
bool WriteFilesViaTemporaryFolder(
    const std::string& path,
    const std::function<bool(const std::string& temp_path, std::string* error)>& write,
    std::string* error);

// For programs (the command-line tools): SIGINT, SIGTERM and SIGHUP first remove the
// temporary files of writes in progress (WriteFileAtomically, WriteViaTemporaryFile), then
// end the process as the signal would have, so that an interrupted write leaves the previous
// output and nothing beside it. Signals the process ignores stay ignored. Not for a library
// inside another program (Python handles its own signals).
void RemoveTemporaryFilesOnTermination();

// Checks that `path` can be created: its folder exists and is writable, and `path` is not
// a folder. Used by tools before long computations.
bool CheckWritableOutputPath(const std::string& path, std::string* error);

}  // namespace dsr

#endif  // DSR_UTIL_ATOMIC_FILE_H_
