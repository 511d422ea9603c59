#pragma once
// What the viewer shows: frames of a project (its linear cache) or of a plain clip, as sRGB
// 8-bit RGBA ready for a texture upload, with a small cache so scrubbing back is instant.
#include <list>
#include <memory>
#include <string>
#include <unordered_map>
#include <vector>

#include "io/clip.h"
#include "project/project.h"

namespace refocus {

class FrameSource {
  public:
    // Opens a project folder / project.json, or any clip ClipReader accepts.
    explicit FrameSource(const std::string& path);
    int width() const { return m_width; }
    int height() const { return m_height; }
    int frames() const { return m_frames; }
    double fps() const { return m_fps; }
    const std::string& label() const { return m_label; }
    // sRGB-encoded RGBA8, width*height*4 bytes.
    const std::vector<unsigned char>& rgba8(int index);
    Image linear(int index);

  private:
    std::unique_ptr<Project> m_project;
    std::unique_ptr<ClipReader> m_clip;
    int m_width = 0, m_height = 0, m_frames = 0;
    double m_fps = 24.0;
    std::string m_label;
    size_t m_capacity = 64;
    std::list<int> m_lru;
    std::unordered_map<int, std::vector<unsigned char>> m_cache;
};

}  // namespace refocus
