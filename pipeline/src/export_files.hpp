#pragma once
// Private to hc::pipeline: how the exports (mesh_export.cpp, raster_export.cpp) put a file in
// place without ever replacing one and without leaving a half-written file.

#include <filesystem>

namespace hc::pipeline::detail {

/// Creates an empty file beside `file` named `<file>.part-XXXXXX` (mkstemp(3): exclusive, a
/// random suffix, so no existing file or symlink is followed), permissions as a new file under
/// the umask. @return its path. @throws hc::InputError naming `file` when it cannot be created.
std::filesystem::path create_temporary_beside(const std::filesystem::path& file);

/// Puts `tmp` at `target` without ever replacing an existing file (link(2) fails with EEXIST
/// when the target appeared since any check), then removes `tmp`. @return false, errno set,
/// when the link fails (tmp is then left for the caller to remove).
bool link_into_place(const std::filesystem::path& tmp, const std::filesystem::path& target);

}  // namespace hc::pipeline::detail
