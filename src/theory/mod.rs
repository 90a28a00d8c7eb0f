pub mod fif;
