// Atomic output (util/atomic_file.h): complete files or none, no temporary files left
// behind, the old file kept on every failure, and one-line errors naming the output.
#include "dsr/util/atomic_file.h"

#include <signal.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <set>
#include <sstream>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "dsr/tests/support/scoped_temp_dir.h"

namespace dsr {
namespace {

using ::testing::ElementsAre;
using ::testing::HasSubstr;
using ::testing::IsEmpty;

std::string ReadAll(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::ostringstream contents;
  contents << in.rdbuf();
  return contents.str();
}

TEST(AtomicFile, WritesCompleteFileAndLeavesNoTemporaryFiles) {
  ScopedTempDir dir;
  const std::string path = dir.File("out.txt");
  std::string error;
  ASSERT_TRUE(WriteFileAtomically(path, "first", &error)) << error;
  EXPECT_EQ(ReadAll(path), "first");
  const std::string big(1 << 20, 'x');
  ASSERT_TRUE(WriteFileAtomically(path, big, &error)) << error;
  EXPECT_EQ(ReadAll(path), big);
  ASSERT_TRUE(WriteFileAtomically(path, "", &error)) << error;
  EXPECT_EQ(ReadAll(path), "");
  EXPECT_THAT(dir.Entries(), ElementsAre("out.txt"));
}

TEST(AtomicFile, TemporaryFileIsHiddenNextToTheOutputWithItsExtension) {
  const std::pair<const char*, const char*> cases[] = {
      {"frame.nii.gz", R"(\.frame\.tmp-[0-9a-f]{8}\.nii\.gz)"},
      {"poses.json", R"(\.poses\.tmp-[0-9a-f]{8}\.json)"},
      {"a.b.MHA", R"(\.a\.b\.tmp-[0-9a-f]{8}\.MHA)"},
      {"noext", R"(\.noext\.tmp-[0-9a-f]{8})"},
  };
  ScopedTempDir dir;
  for (const auto& [name, pattern] : cases) {
    SCOPED_TRACE(name);
    const std::string path = dir.File(name);
    std::string temp_seen;
    std::string error;
    ASSERT_TRUE(WriteViaTemporaryFile(
        path,
        [&](const std::string& temp, std::string* why) {
          temp_seen = temp;
          EXPECT_TRUE(std::filesystem::exists(temp)) << "created before the writer runs";
          EXPECT_FALSE(std::filesystem::exists(path)) << "not published before the rename";
          std::ofstream(temp) << "data";
          return true;
        },
        &error))
        << error;
    const std::filesystem::path temp(temp_seen);
    EXPECT_EQ(temp.parent_path().string(), dir.path());
    EXPECT_THAT(temp.filename().string(), ::testing::MatchesRegex(pattern));
    EXPECT_EQ(ReadAll(path), "data");
    EXPECT_FALSE(std::filesystem::exists(temp));
  }
}

TEST(AtomicFile, FailedWriterKeepsTheOldFileAndRemovesTheTemporary) {
  ScopedTempDir dir;
  const std::string path = dir.File("out.json");
  std::string error;
  ASSERT_TRUE(WriteFileAtomically(path, "old", &error)) << error;
  EXPECT_FALSE(WriteViaTemporaryFile(
      path,
      [](const std::string& temp, std::string* why) {
        std::ofstream(temp) << "partial";
        *why = temp + ": simulated failure";
        return false;
      },
      &error));
  // The writer named the temporary file; the caller sees the real output.
  EXPECT_EQ(error, path + ": simulated failure");
  EXPECT_EQ(ReadAll(path), "old");
  EXPECT_THAT(dir.Entries(), ElementsAre("out.json"));

  EXPECT_FALSE(WriteViaTemporaryFile(
      path, [](const std::string&, std::string*) { return false; }, &error));
  EXPECT_EQ(error, path + ": write failed");
  EXPECT_THAT(dir.Entries(), ElementsAre("out.json"));
}

TEST(AtomicFile, ThrowingWriterRemovesTheTemporary) {
  ScopedTempDir dir;
  std::string error;
  EXPECT_THROW(
      WriteViaTemporaryFile(
          dir.File("out.txt"),
          [](const std::string&, std::string*) -> bool { throw std::runtime_error("boom"); },
          &error),
      std::runtime_error);
  EXPECT_THAT(dir.Entries(), IsEmpty());
}

TEST(AtomicFile, BadOutputPathsAreRejected) {
  ScopedTempDir dir;
  std::string error;
  EXPECT_FALSE(WriteFileAtomically(dir.path(), "x", &error));
  EXPECT_EQ(error, dir.path() + ": is a folder, expected a file name");

  const std::string missing = dir.File("missing/out.txt");
  EXPECT_FALSE(WriteFileAtomically(missing, "x", &error));
  EXPECT_EQ(error, missing + ": folder " + dir.File("missing") + " does not exist");

  std::ofstream(dir.File("plain")) << "file";
  EXPECT_FALSE(WriteFileAtomically(dir.File("plain/out.txt"), "x", &error));
  EXPECT_EQ(error, dir.File("plain/out.txt") + ": " + dir.File("plain") + " is not a folder");

  EXPECT_FALSE(WriteFileAtomically(dir.File("new/"), "x", &error));
  EXPECT_EQ(error, dir.File("new/") + ": ends with '/', expected a file name");

  EXPECT_FALSE(CheckWritableOutputPath("", &error));
  EXPECT_EQ(error, "output path is empty");
  EXPECT_TRUE(CheckWritableOutputPath(dir.File("fresh.txt"), &error)) << error;
  EXPECT_FALSE(std::filesystem::exists(dir.File("fresh.txt"))) << "the check creates nothing";
}

TEST(AtomicFile, UnwritableFolderKeepsTheOldFile) {
  if (geteuid() == 0) GTEST_SKIP() << "root ignores folder permissions";
  ScopedTempDir dir;
  const std::string path = dir.File("out.txt");
  std::string error;
  ASSERT_TRUE(WriteFileAtomically(path, "old", &error)) << error;
  ASSERT_EQ(::chmod(dir.path().c_str(), 0555), 0);
  EXPECT_FALSE(WriteFileAtomically(path, "new", &error));
  EXPECT_EQ(error, path + ": folder " + dir.path() + " is not writable");
  ::chmod(dir.path().c_str(), 0755);
  EXPECT_EQ(ReadAll(path), "old");
  EXPECT_THAT(dir.Entries(), ElementsAre("out.txt"));
}

TEST(AtomicFile, FolderWhereNoFileCanBeCreatedIsAnError) {
  // /proc refuses new files even for root, so this failure path runs under any user.
  if (!std::filesystem::is_directory("/proc/self")) GTEST_SKIP() << "no /proc";
  const std::string path = "/proc/dsr_atomic_file_test.txt";
  std::string error;
  EXPECT_FALSE(WriteFileAtomically(path, "x", &error));
  EXPECT_EQ(error.find('\n'), std::string::npos) << error;
  EXPECT_EQ(error.rfind(path + ": ", 0), 0u) << error;
  EXPECT_THAT(error,
              ::testing::AnyOf(HasSubstr("cannot create a file in folder /proc"),
                               HasSubstr("is not writable")));
}

TEST(AtomicFile, ConcurrentWritersNeverPublishAMixedFile) {
  ScopedTempDir dir;
  const std::string path = dir.File("shared.bin");
  constexpr int kThreads = 4;
  constexpr int kWritesPerThread = 10;
  std::vector<std::string> contents;
  for (int t = 0; t < kThreads; ++t)
    contents.push_back(std::string(64 * 1024, static_cast<char>('a' + t)));
  std::vector<std::thread> threads;
  std::vector<std::string> errors(kThreads);
  for (int t = 0; t < kThreads; ++t) {
    threads.emplace_back([&, t] {
      for (int w = 0; w < kWritesPerThread; ++w) {
        if (!WriteFileAtomically(path, contents[t], &errors[t])) return;
        const std::string seen = ReadAll(path);
        if (std::set<std::string>(contents.begin(), contents.end()).count(seen) == 0) {
          errors[t] = "read a mixed file of " + std::to_string(seen.size()) + " bytes";
          return;
        }
      }
    });
  }
  for (std::thread& thread : threads) thread.join();
  for (const std::string& error : errors) EXPECT_EQ(error, "");
  EXPECT_THAT(dir.Entries(), ElementsAre("shared.bin"));
}

TEST(AtomicFile, TemporaryFolderPublishesEveryFileHeaderLast) {
  ScopedTempDir dir;
  const std::string path = dir.File("volume.mhd");
  std::string error;
  std::string temp_seen;
  ASSERT_TRUE(WriteFilesViaTemporaryFolder(
      path,
      [&](const std::string& temp, std::string* why) {
        temp_seen = temp;
        EXPECT_EQ(std::filesystem::path(temp).filename().string(), "volume.mhd");
        EXPECT_NE(std::filesystem::path(temp).parent_path().string(), dir.path());
        std::ofstream(temp) << "ElementDataFile = volume.raw";
        std::ofstream(std::filesystem::path(temp).parent_path() / "volume.raw") << "voxels";
        return true;
      },
      &error))
      << error;
  EXPECT_THAT(dir.Entries(), ElementsAre("volume.mhd", "volume.raw"));
  EXPECT_EQ(ReadAll(dir.File("volume.raw")), "voxels");
  EXPECT_FALSE(std::filesystem::exists(std::filesystem::path(temp_seen).parent_path()));

  EXPECT_FALSE(WriteFilesViaTemporaryFolder(
      path,
      [&](const std::string& temp, std::string* why) {
        std::ofstream(temp) << "half";
        *why = temp + ": cannot write (disk full)";
        return false;
      },
      &error));
  EXPECT_EQ(error, path + ": cannot write (disk full)");
  EXPECT_EQ(ReadAll(path), "ElementDataFile = volume.raw");
  EXPECT_THAT(dir.Entries(), ElementsAre("volume.mhd", "volume.raw"));
}

}  // namespace
}  // namespace dsr

namespace dsr {
namespace {

// The files in `dir` by name.
std::set<std::string> FilesIn(const std::string& dir) {
  std::set<std::string> names;
  for (const auto& entry : std::filesystem::directory_iterator(dir)) {
    names.insert(entry.path().filename().string());
  }
  return names;
}

// SIGINT or SIGTERM while a write is in progress: the process ends as the signal says, the
// previous output stays, and no temporary file is left beside it.
TEST(AtomicFile, ASignalDuringAWriteRemovesTheTemporaryFile) {
  for (const int signal_number : {SIGINT, SIGTERM}) {
    ScopedTempDir dir;
    const std::string path = dir.path() + "/pan.nii.gz";
    std::string error;
    ASSERT_TRUE(WriteFileAtomically(path, "previous", &error)) << error;
    const pid_t child = fork();
    ASSERT_GE(child, 0);
    if (child == 0) {
      RemoveTemporaryFilesOnTermination();
      WriteViaTemporaryFile(
          path,
          [](const std::string& temp, std::string*) {
            std::ofstream(temp) << "partial";
            for (;;) pause();  // the signal arrives here, mid-write
            return true;
          },
          &error);
      _exit(0);
    }
    // Wait for the temporary file, then signal.
    for (int i = 0; i < 1000 && FilesIn(dir.path()).size() < 2; ++i) usleep(5000);
    ASSERT_EQ(FilesIn(dir.path()).size(), 2u) << "no temporary file appeared";
    kill(child, signal_number);
    int status = 0;
    ASSERT_EQ(waitpid(child, &status, 0), child);
    EXPECT_TRUE(WIFSIGNALED(status) && WTERMSIG(status) == signal_number);
    EXPECT_EQ(FilesIn(dir.path()), std::set<std::string>{"pan.nii.gz"});
    std::ifstream in(path);
    std::string contents;
    in >> contents;
    EXPECT_EQ(contents, "previous");
  }
}

}  // namespace
}  // namespace dsr
