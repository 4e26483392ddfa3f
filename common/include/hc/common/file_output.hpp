#pragma once
/// @file file_output.hpp
/// How hapticloud writes a file the user names (mesh and GeoTIFF exports, session recordings):
/// into an exclusive temporary beside it, then put in place without ever replacing a file, so
/// no half-written file is left and nothing existing is overwritten.

#include <filesystem>

namespace hc {

/// Creates an empty file beside `file` named `<file>.part-XXXXXX` (mkstemp(3): exclusive, a
/// random suffix, so no existing file or symlink is followed), permissions as a new file under
/// the umask. Thread-safe. @return its path. @throws hc::InputError "cannot create a temporary file beside
/// FILE: reason" when it cannot be created (callers prefix their command).
std::filesystem::path create_temporary_beside(const std::filesystem::path& file);

/// Puts `tmp` at `target` without ever replacing an existing file (link(2) fails with EEXIST
/// when the target appeared since any check), then removes `tmp`. @return false, errno set,
/// when the link fails (tmp is then left for the caller to remove).
bool link_into_place(const std::filesystem::path& tmp, const std::filesystem::path& target);

}  // namespace hc
